"""Exceptions shared by the packages."""


class UserError(Exception):
    """A problem the user can fix (bad file, bad value, missing device): printed as one line."""
