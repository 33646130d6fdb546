"""The one error type for a user's mistake (a bad file, field, value or instrument reply).

The CLI turns an :class:`InputError` into one line on stderr and a non-zero exit; anything else is a bug.
``drivers`` and ``battlab`` raise this same type (the dependency direction is protocols ← drivers ← battlab).
"""


class InputError(ValueError):
    """Bad input from the user: the message names what, where, and what was expected."""
