"""Errors that mean "the input is wrong": the CLI prints their message on one line and exits with code 2."""


class DgtdInputError(ValueError):
    """A problem, network, config or file that dgtd refuses, with a message that says how to fix it."""
