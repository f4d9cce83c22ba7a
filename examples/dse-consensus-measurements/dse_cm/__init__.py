"""The consensus-on-measurements Kalman filter, a plug-in filter of dse's compare arena (`dse_cm.filter`)."""
from .filter import ConsensusOnMeasurements, Parameters

__all__ = ["ConsensusOnMeasurements", "Parameters"]
