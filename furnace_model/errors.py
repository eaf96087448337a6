"""Errors that reach a user: each names the file and the place in it that is wrong."""

from __future__ import annotations


class FurnaceError(Exception):
    """Base of the errors a command-line front end reports as a message, not a traceback."""

    exit_code = 1


class DataError(FurnaceError):
    """A data file breaks the tabular contract (CONTRACTS.md section 1)."""

    def __init__(self, file: str, message: str, column: str | None = None, row: int | None = None,
                 row_label: str = "row"):
        self.file, self.column, self.row = file, column, row
        where = [str(file)]
        if column is not None:
            where.append(f"column '{column}'")
        if row is not None:
            where.append(f"{row_label} {row}")
        super().__init__(f"{', '.join(where)}: {message}")


class DataWarning(UserWarning):
    """Data that is read but is not what its description promises (a thermocouple column
    the furnace names and the file lacks): said once on stderr, the rest read as given."""

    def __init__(self, file: str, message: str, column: str | None = None):
        where = [str(file)] + ([f"column '{column}'"] if column is not None else [])
        super().__init__(f"{', '.join(where)}: {message}")


class ConfigError(FurnaceError):
    """A YAML file (scenario, daemon config) has a wrong key, type or value."""

    exit_code = 2

    def __init__(self, file: str, path: str, message: str):
        self.file, self.path = file, path
        super().__init__(f"{file}: {path or '<top level>'}: {message}")
