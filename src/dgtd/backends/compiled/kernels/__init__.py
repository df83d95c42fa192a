"""One compiled kernel per algorithm, each in a file of its own named after it; every module here is imported by
`dgtd.backends.compiled` and registers itself with `dgtd.backends.compiled.kernel`."""
