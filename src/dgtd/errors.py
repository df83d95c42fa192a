"""Errors that mean "the input is wrong": the CLI prints their message on one line and exits with code 2; and the
wrapper that tells a user's own code failing from dgtd's."""


class DgtdInputError(ValueError):
    """A problem, network, config or file that dgtd refuses, with a message that says how to fix it."""


class UserCodeError(DgtdInputError):
    """An exception raised inside a user's own code (their env, policy or features), named in one line; its
    traceback is the ``__cause__``, which ``dgtd --debug`` prints."""


def user_error(what: str, error: Exception) -> UserCodeError:
    """The one line for ``error`` raised by ``what``, a user's code; raise it ``from error``."""
    return UserCodeError(f"{what} raised {type(error).__name__}: {error} (dgtd --debug ... shows its traceback)")


def call_user(what: str, function, *args, **kwargs):
    """``function(*args, **kwargs)``, where ``function`` is a user's code: any exception it raises (a dgtd refusal
    passes as it is), and a ``sys.exit`` it calls, becomes a `UserCodeError` that names ``what`` and keeps the
    original as its cause."""
    try:
        return function(*args, **kwargs)
    except DgtdInputError:
        raise
    except SystemExit as e:  # sys.exit() in a user's code would end dgtd with that code, no results and no word
        raise UserCodeError(
            f"{what} called sys.exit({'' if e.code is None else repr(e.code)}): a function dgtd calls must return, "
            "not end the program"
        ) from e
    except Exception as e:  # noqa: BLE001  (anything the user's code raises is theirs to see)
        raise user_error(what, e) from e


def user_numbers(what: str, value):
    """What a user's code (``what``) returned, as a float64 array; a one-line refusal where it is not real numbers
    (text, None, complex numbers: NumPy would raise deep in dgtd, or drop the imaginary part)."""
    import numpy as np

    try:
        kind = np.asarray(value).dtype.kind
    except (TypeError, ValueError):  # ragged lists
        kind = "O"
    if kind not in "biuf":
        text = " ".join(repr(value).split())  # one line
        shown = text if len(text) <= 60 else text[:57] + "..."
        raise DgtdInputError(f"{what} returned {shown}, not real numbers")
    return np.asarray(value, dtype=np.float64)
