"""Estimators over frames (docs/math.md §7 for their mirror hypotheses, §15 for unknowns).

``ekf`` (:class:`Ekf`, filterpy's EKF or UKF, one hypothesis per mirror side) updates frame by
frame; ``gtsam-smoother`` (:class:`GtsamSmoother`, a GTSAM factor graph smoothed by ISAM2)
re-solves all frames seen so far. Both keep both mirror hypotheses until the data decide
(:mod:`~estimators.sequential.mirror_hypotheses`); the nuisance states of a non-cooperative
emitter are in the ``nuisance_*`` modules; the smoother's factors in
:mod:`~estimators.sequential.smoother_graph`.
"""

from estimators.sequential.ekf import Ekf
from estimators.sequential.gtsam_smoother import GtsamSmoother

__all__ = ["Ekf", "GtsamSmoother"]
