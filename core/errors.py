"""Errors that are the user's to fix: the CLI prints them as one line and exits 2."""


class UsageError(ValueError):
    """Bad input: a missing file, an unparseable layer, an unknown processor, a bad value."""


class OutputError(RuntimeError):
    """The output could not be written (a full disk, a quota, an I/O error): not the user's input, so the
    command exits 1; the previous output and its files are unchanged."""


class StageError(UsageError):
    """A prim holds a value usdbake cannot bake; the message names prim, attribute and value."""

    def __init__(self, prim: str, attribute: str, problem: str):
        self.prim, self.attribute = prim, attribute
        super().__init__(f"{prim}.{attribute}: {problem}" if attribute else f"{prim}: {problem}")
