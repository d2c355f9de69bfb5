"""The JSON of interfaces.md, both directions, shared by the API and the CLI (I/O edge)."""
