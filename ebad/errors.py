"""Project-wide exception for user mistakes (bad files, fields, arguments)."""


class UserError(ValueError):
    """Bad input from a user; the message names the file, field or argument."""
