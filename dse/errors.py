"""Exceptions the command line turns into one clear line and an exit code."""
import unicodedata


def printable(text: str) -> str:
    """`text` with control, format (bidirectional overrides, zero-width) and unassigned
    characters escaped as \\uXXXX, so that a message echoing user input stays one honest line."""
    return "".join(f"\\u{ord(c):04x}" if unicodedata.category(c) in ("Cc", "Cf", "Cs", "Co", "Cn", "Zl", "Zp")
                   else c for c in str(text))


class ScenarioError(ValueError):
    """Invalid user input, tied to the scenario field that is wrong.

    `field` is a dotted path such as ``graph.kind`` or ``noise.r``; the message always
    starts with it so that a user can find the line in their TOML file.
    """

    def __init__(self, field: str, reason: str):
        self.field = printable(field)
        self.reason = printable(reason)
        super().__init__(f"{self.field}: {self.reason}")

    def __reduce__(self):  # raised in a worker process, it must survive pickling
        return (ScenarioError, (self.field, self.reason))


class OutputError(RuntimeError):
    """The output directory cannot be used (not writable, not a directory, disk full)."""


class CacheMiss(RuntimeError):
    """A stage result was required from the cache (``dse verify``) but is not there."""


class NumericalError(ArithmeticError):
    """A NaN or inf appeared where a finite number is required; says where."""

    def __init__(self, stage: str, scenario: str, where: str):
        self.stage, self.scenario, self.where = stage, scenario, where
        super().__init__(f"non-finite value in stage '{stage}', scenario '{scenario}', {where}")

    def __reduce__(self):  # raised in a worker process, it must survive pickling
        return (NumericalError, (self.stage, self.scenario, self.where))


class NumericalLimit(NumericalError):
    """A valid scenario asks for a number that float64 cannot give: a gain below the rounding unit
    of 1 (so that ``1 - gain`` rounds to 1 and a stable recursion looks marginally stable), a
    steady state that exists in exact arithmetic but not at this precision. Like any NumericalError
    it is a one-line exit 3 on the command line and a `numerical-error` point in a sweep; `what`
    says which quantity and why."""

    def __init__(self, what: str):
        self.stage, self.scenario, self.where = "", "", what
        ArithmeticError.__init__(self, f"beyond float64: {what}")

    def __reduce__(self):  # raised in a worker process, it must survive pickling
        return (NumericalLimit, (self.where,))


class UsageError(ScenarioError):
    """An invalid argument of a function of the Python API (`dse.run(..., trials=-3)`,
    `dse.check(123)`): the Python side of the command line's usage errors. `field` is the
    parameter's name; the message is the one line the command line would print."""

    def __reduce__(self):
        return (UsageError, (self.field, self.reason))
