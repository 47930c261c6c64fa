"""A small demo robot for `make run` and the README examples (not part of the gateway)."""
