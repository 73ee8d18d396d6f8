"""The package's version, in the lowest layer so that any module can name it (the package root,
the CLI, batch logs and records, download requests) without importing the root."""

__version__ = "0.1.0"
