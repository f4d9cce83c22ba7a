"""Bring your own distributed filter: the public protocol of the compare arena.

A researcher's filter is a subclass of `NetworkFilter` (see `dse.plugin.interface` for the protocol and
docs/plugins.md for a worked example). It enters the arena in one of two ways:

* a compare scenario's table ``[estimators.<name>]`` with ``factory = "package.module:Class"`` and its
  parameters;
* an installed package's entry point in the group ``dse.estimators`` (``<name> = "package.module:Class"``),
  then ``[estimators.<name>]`` with no factory, or ``dse arena <name>`` for its leaderboard.

It is run by the same harness, on the same random numbers, and checked by the same claims as every
built-in estimator (`dse.plugin.harness`, `dse.plugin.declare`).
"""
from .harness import PluginFault
from .interface import Inbox, LinearStep, Messages, Network, NetworkFilter, NoParameters, Problem

__all__ = ["NetworkFilter", "Messages", "Problem", "Inbox", "Network", "LinearStep", "NoParameters", "PluginFault"]
