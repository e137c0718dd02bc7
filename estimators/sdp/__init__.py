"""The SDP relaxation of the closed-form CLS (docs/math.md §11), solved by Clarabel.

Estimator: ``sdp-cls`` (:class:`SdpCls`). The relaxation is lifted and whitened in
:mod:`~estimators.sdp.sdp_lift`, solved (a ladder of solver settings) in
:mod:`~estimators.sdp.sdp_solvers`, and its minimisers read back in
:mod:`~estimators.sdp.sdp_cls`, which is also where a single relaxation is solved for
``emitterbench validate`` (:func:`solve_sdp_relaxation`). The reference path is the batch:
``SdpCls.estimate`` is the batch of one trial.
"""

from estimators.sdp.sdp_cls import SdpCls, SdpSolution, solve_sdp_relaxation

__all__ = ["SdpCls", "SdpSolution", "solve_sdp_relaxation"]
