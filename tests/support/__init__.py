"""Helpers the tests share: real processes, real sockets, polling to deadlines."""
