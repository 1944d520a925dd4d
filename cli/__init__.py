"""The `usdbake` command: parse arguments, call the library, format what it returns."""
