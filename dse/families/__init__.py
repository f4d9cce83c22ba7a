"""This project's scenario families, one subpackage each (the registry is `dse.registry`).

`dse.families.from_dict`, `.paper`, `.families`, ... are the registry's functions, loaded on first
use (a family's stages import this package, and must not depend on the registry's code).
"""
import importlib


def __getattr__(name: str):
    return getattr(importlib.import_module("dse.registry"), name)
