"""Plug-in filters that break the protocol (`dse.plugin`), one way each, for the fault tests
(tests/test_plugin_faults.py). Every one is the local Kalman filter of `twins.LocalTwin` until the step
(`AT`) where it misbehaves, so that the harness has something to drop mid-run."""
from __future__ import annotations

import numpy as np

from pydantic import BaseModel, ConfigDict, Field

from dse.plugin import LinearStep, Messages, NetworkFilter

from .twins import LocalTwin

#: the step at which a filter that misbehaves mid-run does so
AT = 3


class RaisesInInit(LocalTwin):
    """Its constructor raises."""

    def __init__(self, problem, params, trials):
        raise RuntimeError("cannot build")


class RaisesInStep(LocalTwin):
    """Its step raises at step AT."""

    def step(self, k, y, network):
        if k == AT:
            raise RuntimeError("boom")
        return super().step(k, y, network)


class RaisesInCovariance(LocalTwin):
    """Its covariance() raises at step AT."""

    def covariance(self):
        if self.k == AT:
            raise KeyError("no covariance")
        return super().covariance()


class SingularCovariance(LocalTwin):
    """Its covariance() is the zero matrix from step AT on."""

    def covariance(self):
        P = super().covariance()
        return 0.0 * P if self.k >= AT else P


class CovarianceWrongShape(LocalTwin):
    """Its covariance() has one node too many."""

    def covariance(self):
        P = super().covariance()
        return np.concatenate([P, P[:1]])


class ReturnsNaN(LocalTwin):
    """Returns NaN at one node from finite inputs at step AT."""

    def step(self, k, y, network):
        est = super().step(k, y, network)
        if k == AT:
            est = est.copy()
            est[0, 0, 0] = np.nan
        return est


class WrongShape(LocalTwin):
    """Returns one state coordinate too many."""

    def step(self, k, y, network):
        est = super().step(k, y, network)
        return np.concatenate([est, est[:, :1]], axis=1)


class NotAnArray(LocalTwin):
    """Returns None instead of its estimates."""

    def step(self, k, y, network):
        super().step(k, y, network)
        return None


class IntegerEstimates(LocalTwin):
    """Returns its estimates rounded to integers (an int array)."""

    def step(self, k, y, network):
        return np.rint(super().step(k, y, network)).astype(np.int64)


class WritesY(LocalTwin):
    """Subtracts its prediction from the measurements in place."""

    def step(self, k, y, network):
        y -= 1.0
        return super().step(k, y, network)


class UnlocksY(LocalTwin):
    """Makes the measurements writeable again and overwrites them (every other filter would see zeros)."""

    def step(self, k, y, network):
        y.flags.writeable = True
        y[...] = 0.0
        return super().step(k, y, network)


class WritesProblem(LocalTwin):
    """Overwrites the graph it was given (shared with the built-ins)."""

    def step(self, k, y, network):
        self.problem.edges[0, 0] = 1
        return super().step(k, y, network)


class Sender(LocalTwin):
    """The local filter that also broadcasts its estimate (n numbers, one exchange per step) and ignores
    what it hears: the base of the filters that send more than they declare."""

    @classmethod
    def sends(cls, problem, params):
        return Messages(problem.n, per="step", exchanges=1)

    def step(self, k, y, network):
        est = super().step(k, y, network)
        self.inbox = network.exchange(est)
        return est


class WritesInbox(Sender):
    """Zeroes the messages it received."""

    def step(self, k, y, network):
        est = super().step(k, y, network)
        self.inbox.values[...] = 0.0
        return est


class WiderMessage(Sender):
    """Declares messages of one number, sends n."""

    @classmethod
    def sends(cls, problem, params):
        return Messages(1, per="step", exchanges=1)


class ExtraExchange(Sender):
    """Declares one exchange per step, makes two at step AT."""

    def step(self, k, y, network):
        est = super().step(k, y, network)
        if k == AT:
            network.exchange(est)
        return est


class UndeclaredSender(Sender):
    """Declares that it sends nothing, then sends."""

    @classmethod
    def sends(cls, problem, params):
        return None


class TooSlow(LocalTwin):
    """Burns a fixed amount of CPU every step (about 10⁸ floating-point operations: tens of milliseconds),
    against a `time_limit` of a millisecond in its table."""

    def step(self, k, y, network):
        a = np.full((200, 200), 1e-3)
        for _ in range(6):
            a = a @ a + 1e-3
        return super().step(k, y, network)


class NotUnbiased(LocalTwin):
    """Declares matrices that lose a tenth of the prediction: A (1 ⊗ I) + B H ≠ 1 ⊗ I."""

    def matrices(self, k):
        step = super().matrices(k)
        return LinearStep(0.9 * step.A, step.B)


class MatricesWrongShape(LocalTwin):
    """Declares a B without its last node's columns."""

    def matrices(self, k):
        step = super().matrices(k)
        return LinearStep(step.A, step.B[:, :-1])


class MatricesNotALinearStep(LocalTwin):
    """Declares its matrices as a tuple."""

    def matrices(self, k):
        step = super().matrices(k)
        return step.A, step.B


# -- declarations that are refused before anything runs (ScenarioError naming the key) ------------------------

class NotAFilter:
    """Not a NetworkFilter subclass."""


class NoStep(NetworkFilter):
    """Does not implement step."""


class EquivariantWithoutShift(NetworkFilter):
    equivariant = True

    def step(self, k, y, network):
        return np.zeros((self.problem.N, self.problem.n, self.trials))


class LinearWithoutMatrices(EquivariantWithoutShift):
    equivariant = False
    linear = True


class BadCovarianceLaw(EquivariantWithoutShift):
    equivariant = False
    covariance_law = "exact"


class Tuned(LocalTwin):
    """A filter with a parameter (to test that its table is validated by its own schema)."""

    class Parameters(BaseModel):
        model_config = ConfigDict(extra="forbid", frozen=True)
        gain: float = Field(0.5, gt=0, le=1, description="a gain in (0, 1]")


class BadSends(LocalTwin):
    """Declares messages of zero numbers (`Messages` refuses them)."""

    @classmethod
    def sends(cls, problem, params):
        return Messages(0)


class SendsNotMessages(LocalTwin):
    """Declares its messages as a dict."""

    @classmethod
    def sends(cls, problem, params):
        return {"scalars": problem.n}


class DivergesThenNaN(LocalTwin):
    """Not a fault: its estimates overflow (1e200 at step AT − 1, inf·0 = NaN after): a diverging filter's NaN is a
    result, reported as not finite, not a protocol violation."""

    def step(self, k, y, network):
        est = super().step(k, y, network)
        if k == AT - 1:
            return est * 1e200
        return est * np.nan if k >= AT else est
