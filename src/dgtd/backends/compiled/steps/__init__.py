"""One compiled per-agent step per algorithm, each in a file of its own named after it; every module here is imported
by `dgtd.backends.compiled` and registers its step with `dgtd.backends.compiled.step.register`."""
