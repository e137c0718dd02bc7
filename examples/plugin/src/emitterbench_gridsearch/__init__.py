"""An emitterbench plug-in: Doppler-only maximum likelihood by grid search and refinement.

Registered under the entry-point group ``emitterbench.estimators`` as ``doppler-grid``, so that
``emitterbench list`` shows it once this distribution is installed; without installing, the
path ``emitterbench_gridsearch:DopplerGridSearch`` works wherever an estimator name does.
"""

from emitterbench_gridsearch.doppler_grid import DopplerGridSearch

__all__ = ["DopplerGridSearch"]
