"""The one error type raised at the boundaries of the core (files, user values)."""


class ClothFitError(Exception):
    """Bad input: a missing/corrupt file, a wrong value, mismatched data.

    The message always names the file or the value at fault, so that the CLI
    can print it and the Blender operators can report it verbatim.
    """
