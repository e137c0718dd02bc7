"""Maximum likelihood, the reference estimator (docs/math.md §10, with unknowns §15).

Estimator: ``ml`` (:class:`MaximumLikelihood`): Levenberg-Marquardt on the whitened residuals
from every closed-form candidate. One trial is solved in :mod:`~estimators.ml.ml`
(``scipy.optimize.least_squares``); many trials at once in :mod:`~estimators.ml.ml_batch`
(a vectorised MINPACK Levenberg-Marquardt, :mod:`~estimators.ml.minpack_batch`).
"""

from estimators.ml.ml import MaximumLikelihood, MlSolution, solve_maximum_likelihood

__all__ = ["MaximumLikelihood", "MlSolution", "solve_maximum_likelihood"]
