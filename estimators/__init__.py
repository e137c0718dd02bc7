"""Localization estimators behind one interface (:class:`estimators.base.Estimator`).

Built-ins: ``cls``, ``cls-paper``, ``cls-as-printed``, ``lls-toa``, ``lls-rss``, ``ml``,
``sdp-cls``, ``ekf``, ``gtsam-smoother``.
Look them up with :func:`make_estimator`; plug-ins register under the entry-point group
``emitterbench.estimators``.
"""

from estimators import moved
from estimators.base import (
    BatchEstimator,
    Estimate,
    Estimator,
    SequentialEstimator,
    finalize_estimate,
)
from estimators.registry import all_entries, estimator_class, make_estimator

moved.install()

__all__ = [
    "BatchEstimator",
    "Estimate",
    "Estimator",
    "SequentialEstimator",
    "all_entries",
    "estimator_class",
    "finalize_estimate",
    "make_estimator",
]
