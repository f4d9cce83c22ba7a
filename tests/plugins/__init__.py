"""Plug-in filters the tests register through `dse.plugin` (twins of built-ins, a biased one, bad ones)."""
