"""Where samples come from: a model (`dgtd.sources.model`); a simulator or recorded data supplies the same interface."""
