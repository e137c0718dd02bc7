"""Maximum likelihood, the reference estimator (docs/math.md §10, with unknowns §15).

Estimator: ``ml`` (:class:`MaximumLikelihood`): Levenberg-Marquardt on the whitened residuals
from every closed-form candidate. The reference path is the batch
(:mod:`~estimators.ml.ml_batch`, MINPACK's Levenberg-Marquardt vectorised over trials in
:mod:`~estimators.ml.minpack_batch`): ``MaximumLikelihood.estimate`` is the batch of one trial.
"""

from estimators.ml.ml import MaximumLikelihood, whitened_residual_jacobian, whitened_residuals

__all__ = ["MaximumLikelihood", "whitened_residual_jacobian", "whitened_residuals"]
