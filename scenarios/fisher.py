r"""The Fisher information of the emitter's position and its inverse, the CRLB (MATH §8).

With independent Gaussian noise the information is a sum over the samples ``k`` and the
modalities used,

.. math::

    J = \sum_k \Big( \frac{\nabla\tau_k \nabla\tau_k^\top}{\sigma_\tau^2}
        + \frac{\nabla f_k \nabla f_k^\top}{\sigma_f^2}
        + \frac{\nabla P_k \nabla P_k^\top}{\sigma_P^2} \Big)
      = \sum_{\text{rows}} g\,g^\top,\qquad g = \nabla h / \sigma,
    \qquad \mathrm{CRLB} = J^{-1},\qquad \text{RMSE bound} = \sqrt{\operatorname{tr} J^{-1}},

with the gradients of :mod:`scenarios.measurement_model` and the σ's, ``γ``, ``c``, the emitter
height and the RSS model of a :class:`~scenarios.types.MeasurementSet`. It depends only on the
world (geometry and noise), not on measured values, so it lives beside the measurement model
and everything downstream (planners, estimators, comparison) uses this one copy.

The position has ``d`` coordinates, ``(x_s, y_s)`` at a known emitter height (``d = 2``, every
scenario today) or ``(x_s, y_s, z_s)`` (``d = 3``); ``d`` is never assumed here: it is the last
axis of the gradients of :mod:`scenarios.measurement_model` (one column per coordinate of
``emitter_m``), and every information and covariance is ``(..., d, d)``.

Layers, each vectorised: ``position_m`` and ``velocity_mps`` have shape ``(..., N, 3)`` and
``emitter_m`` shape ``(..., d)``, leading axes broadcasting as in the measurement model (many
emitter positions for a geometry map, many headings for a planner):

- :func:`whitened_gradients`: the rows ``g = ∇h_k/σ``, one block of ``N`` per modality;
- :func:`gram_information`: ``Σ g gᵀ`` of any stack of such rows (the one place the sum is
  formed);
- :func:`per_sample_information`: ``J_k`` of each sample; :func:`information_at_samples`: ``J``
  of given samples; :func:`fisher_information` and :func:`fisher_information_per_frame`: ``J``
  of a measurement set's own samples, all of them or per frame and accumulated;
- :func:`information_statistics`, :func:`frame_statistics`: the sufficient statistics of groups
  of samples (a measurement set's frames), from which :class:`InformationStatistics` forms
  ``J`` of any union of groups with the nuisance parameters shared over it (MATH §15);
- :func:`regular_symmetric`, :func:`inverse_symmetric`, :func:`rmse_bound_m`: the algebra of the
  bound in any dimension, one rule of regularity; :func:`regular_2x2` and :func:`inverse_2x2`
  are its closed form for ``d = 2``.

Modalities are ``"toa"``, ``"doppler"``, ``"rss"`` or a combination, given as a tuple or as a
string joined by ``+`` (``"toa+doppler"``); see :func:`parse_modalities`.

Nuisance parameters (MATH §15). With an unknown carrier offset δ every Doppler row gains the
column ``∂f_k/∂δ = 1``, with an unknown emission time b every ToA row the column
``∂τ_k/∂b = 1``. The position's block of the inverse of the enlarged information is the
inverse of its Schur complement, and because each nuisance column is constant over one
modality's rows (one σ) and zero elsewhere, that complement is the Gram matrix of the rows with
each affected modality's block *centred* over its samples: ``J = Σ (g − ḡ)(g − ḡ)ᵀ``. So
``unknowns`` centres blocks and everything else is unchanged.

The terrain prior (MATH §8). When ``data`` carries a :class:`~scenarios.terrain.Terrain` and
the height is unknown (``unknowns`` holds ``"emitter_height_m"`` and the position is
``(x_s, y_s, z_s)``), the prior ``z_s − h(x_s, y_s) ~ N(0, σ_m²)`` is one more whitened row,
``(−h_x, −h_y, 1)/σ_m`` (:func:`terrain_row`): :func:`whitened_jacobian` ends with it and
:class:`InformationStatistics` adds its Gram matrix once to the information of any set of
frames. The information is then the Bayesian one of the measurements and the prior (the CRLB
of the data with the terrain as one more measurement of the height above the ground, 0 ± σ_m);
as ``σ_m → 0`` it tends to the bound constrained to the surface. The per-sample functions
(:func:`whitened_gradients`, :func:`information_at_samples`, :func:`per_sample_information`)
hold the samples' rows only.

One nuisance over any set of frames. An estimator that uses some frames faces one δ and one b
over the union of their samples, so the centring runs over that union: the information of a
set of frames is not the sum of the frames' own (centred) informations. :func:`frame_statistics`
keeps, per frame, what any union needs (:class:`InformationStatistics`: the Gram matrix of the
rows whose nuisance is known, and per centred modality the Gram matrix of the rows centred
within the frame, their mean and the frame's count); :meth:`InformationStatistics.information`
forms the information of any set of frames from them, and "every frame so far", "the last
frame" and "these frames" are that one function of different sets.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from scenarios import measurement_model as model
from scenarios.nuisance import AFFECTED_MODALITY, HEIGHT_UNKNOWN, nuisance_unknowns, parse_unknowns
from scenarios.terrain import offset_gradient
from scenarios.types import MODALITIES, NOISE_FIELD, MeasurementSet

FloatArray = NDArray[np.float64]
BoolArray = NDArray[np.bool_]

MODALITY_SETS: dict[str, tuple[str, ...]] = {
    "toa": ("toa",),
    "doppler": ("doppler",),
    "rss": ("rss",),
    "toa+doppler": ("toa", "doppler"),
}
"""The modality subsets reported by ``emitterbench crlb``."""

SINGULAR_RTOL = 1e-12
"""A symmetric ``d × d`` matrix counts as singular when ``det J ≤ SINGULAR_RTOL · |Π_i J_ii|``
(``|J₁₁ J₂₂|`` for ``d = 2``): by Hadamard's inequality ``det J ≤ Π J_ii`` for a positive
semi-definite ``J``, and the ratio is the determinant of its correlation matrix, whatever the
units of each coordinate."""


def parse_modalities(modalities: str | Iterable[str]) -> tuple[str, ...]:
    """The modalities as a tuple, in the order given.

    A string is a key of :data:`MODALITY_SETS` or names joined by ``+``; any other iterable
    holds the names. Raises ``ValueError`` for an empty set or a name not in
    :data:`~scenarios.types.MODALITIES`.
    """
    if isinstance(modalities, str):
        modalities = MODALITY_SETS.get(modalities, tuple(modalities.split("+")))
    chosen = tuple(modalities)
    unknown = sorted(set(chosen) - set(MODALITIES))
    if unknown or not chosen:
        raise ValueError(f"modalities: expected a subset of {MODALITIES}, got {chosen!r}")
    return chosen


def _whitened_blocks(
    position_m: ArrayLike,
    velocity_mps: ArrayLike,
    emitter_m: ArrayLike,
    data: MeasurementSet,
    modalities: str | Iterable[str],
    unknowns: Iterable[str] = (),
) -> list[FloatArray]:
    """One ``∇h_k/σ`` block of shape ``(..., N, d)`` per modality, in the order given; the
    block of a modality with an unknown nuisance parameter centred over its samples (§15)."""
    emitter = np.asarray(emitter_m, dtype=float)
    centred = {AFFECTED_MODALITY[name] for name in nuisance_unknowns(unknowns)}
    blocks = []
    for modality in parse_modalities(modalities):
        sigma = data.noise.for_modality(modality)
        if sigma is None:
            raise ValueError(
                f"noise.{NOISE_FIELD[modality]}: needed for the {modality} information but not "
                "given; give the σ or drop the modality"
            )
        if modality == "toa":
            gradient = model.toa_jacobian(
                position_m, emitter, data.speed_of_light_mps, data.emitter_height_m
            )
        elif modality == "doppler":
            gradient = model.doppler_jacobian(
                position_m, velocity_mps, emitter, data.gamma_per_m, data.emitter_height_m
            )
        else:
            if data.rss_model is None:
                raise ValueError("rss_model: needed for the RSS information but not given")
            gradient = model.rss_jacobian(
                position_m, emitter, data.rss_model, data.emitter_height_m
            )
        if modality in centred:
            gradient = gradient - gradient.mean(axis=-2, keepdims=True)
        blocks.append(gradient / sigma)
    return blocks


def whitened_gradients(
    position_m: ArrayLike,
    velocity_mps: ArrayLike,
    emitter_m: ArrayLike,
    data: MeasurementSet,
    modalities: str | Iterable[str] = "toa+doppler",
    *,
    unknowns: Iterable[str] = (),
) -> FloatArray:
    """The rows ``g = ∇h_k/σ`` of MATH §8 at the given samples, shape ``(..., M·N, d)``.

    Parameters
    ----------
    position_m, velocity_mps : (..., N, 3)
        Sample positions and velocities (need not be ``data``'s own: a planned frame works).
    emitter_m : (..., d)
        Where the gradients are taken; leading axes broadcast with the samples'.
    data : MeasurementSet
        Supplies the constants: the σ's, ``γ``, ``c``, the emitter height, the RSS model. A
        modality absent from its measurements may still be used if its σ is given (the
        information does not need measured values).
    modalities : str or iterable of str
        See :func:`parse_modalities`; the ``M`` blocks of ``N`` rows follow this order.
    unknowns : iterable of str
        Nuisance parameters to eliminate (MATH §15): the affected blocks are centred over these
        samples. Default none: the samples alone, with the emitter's carrier and clock known.

    Raises ``ValueError`` naming a missing σ or RSS model.
    """
    blocks = _whitened_blocks(position_m, velocity_mps, emitter_m, data, modalities, unknowns)
    return np.concatenate(blocks, axis=-2)


def gram_information(whitened_rows: ArrayLike, *, row_axis: int = -2) -> FloatArray:
    """``J = Σ_rows g gᵀ`` of whitened gradient rows ``(..., n_rows, p)``: shape ``(..., p, p)``.

    With the rows of :func:`whitened_gradients` (``p = d``) this is the information of MATH §8;
    any other stack of rows ``∇h/σ`` of independent Gaussian measurements gives its information
    too (a filter's state of ``p`` entries). ``row_axis`` names the axis of the rows when it is
    not the one before the last (``0``: rows first, ``(n_rows, ..., p)``). The rows are added
    in order, ``s = 0; s += g gᵀ``, so an entry depends on its own stack of rows alone, whatever
    the other stacks, their number or the layout: the batch and one-trial paths of an
    estimator get the same bits.
    """
    rows = np.asarray(whitened_rows, dtype=float)
    axis = row_axis % max(rows.ndim, 1)
    if rows.ndim < 2 or axis == rows.ndim - 1:
        raise ValueError(
            f"whitened_rows: expected rows along axis {row_axis} and the gradient last, got "
            f"shape {rows.shape}"
        )
    p = rows.shape[-1]
    pairs = [(i, j) for i in range(p) for j in range(i, p)]
    products = np.stack([rows[..., i] * rows[..., j] for i, j in pairs], axis=-1)
    if products.shape[axis] == 0:
        sums = np.zeros(products.shape[:axis] + products.shape[axis + 1 :])
    else:  # a reduction over an outer axis of a contiguous array adds row after row
        sums = np.add.reduce(products, axis=axis, initial=0.0)
    information = np.empty((*sums.shape[:-1], p, p))
    for k, (i, j) in enumerate(pairs):
        information[..., i, j] = sums[..., k]
        information[..., j, i] = sums[..., k]
    return information


def per_sample_information(
    position_m: ArrayLike,
    velocity_mps: ArrayLike,
    emitter_m: ArrayLike,
    data: MeasurementSet,
    modalities: str | Iterable[str] = "toa+doppler",
) -> FloatArray:
    """Each sample's term ``J_k = Σ_modalities ∇h_k∇h_kᵀ/σ²`` of MATH §8, shape ``(..., N, d, d)``.

    Arguments as for :func:`whitened_gradients`; summed over ``N`` it is
    :func:`information_at_samples`.
    """
    blocks = np.stack(_whitened_blocks(position_m, velocity_mps, emitter_m, data, modalities))
    return np.einsum("m...ki,m...kj->...kij", blocks, blocks)


def information_at_samples(
    position_m: ArrayLike,
    velocity_mps: ArrayLike,
    emitter_m: ArrayLike,
    data: MeasurementSet,
    modalities: str | Iterable[str] = "toa+doppler",
) -> FloatArray:
    """``J`` of MATH §8 over the given samples, units 1/m², shape ``(..., d, d)``.

    Arguments as for :func:`whitened_gradients`: the samples may be any (a planned frame,
    many headings at once), the constants are ``data``'s.
    """
    return gram_information(
        whitened_gradients(position_m, velocity_mps, emitter_m, data, modalities)
    )


def terrain_row(
    data: MeasurementSet, emitter_m: ArrayLike, unknowns: Iterable[str]
) -> FloatArray | None:
    """The terrain prior's whitened row ``∇(z_s − h(x_s, y_s))/σ_m = (−h_x, −h_y, 1)/σ_m`` at
    ``emitter_m`` ``(..., 3)``, shape ``(..., 1, 3)`` (MATH §8, :mod:`scenarios.terrain`); None
    unless ``data`` carries a terrain, ``unknowns`` holds the height and the position has three
    coordinates (with the height known the terrain is not used)."""
    emitter = np.asarray(emitter_m, dtype=float)
    terrain = data.terrain
    if terrain is None or emitter.shape[-1] != 3 or HEIGHT_UNKNOWN not in parse_unknowns(unknowns):
        return None
    return offset_gradient(terrain, emitter)[..., None, :] / terrain.sigma_m


def whitened_jacobian(
    data: MeasurementSet,
    emitter_m: ArrayLike,
    modalities: str | Iterable[str] = "toa+doppler",
    *,
    unknowns: Iterable[str] | None = None,
) -> FloatArray:
    """Rows ``∇h_k/σ`` of every sample of ``data`` and modality, shape ``(..., n_rows, d)``,
    and last the terrain prior's row where it applies (:func:`terrain_row`).

    :func:`whitened_gradients` at ``data``'s own samples (MATH §8); ``emitter_m`` is
    ``(..., d)``. ``unknowns`` defaults to ``data.unknowns`` (MATH §15); ``()`` gives the rows
    of a cooperative emitter at a known height.
    """
    unknowns = data.unknowns if unknowns is None else unknowns
    rows = whitened_gradients(
        data.position_m, data.velocity_mps, emitter_m, data, modalities, unknowns=unknowns
    )
    prior = terrain_row(data, emitter_m, unknowns)
    if prior is None:
        return rows
    return np.concatenate([rows, np.broadcast_to(prior, (*rows.shape[:-2], 1, 3))], axis=-2)


def fisher_information(
    data: MeasurementSet,
    emitter_m: ArrayLike,
    modalities: str | Iterable[str] = "toa+doppler",
    *,
    unknowns: Iterable[str] | None = None,
) -> FloatArray:
    """``J`` of MATH §8 over all samples of ``data``, shape ``(..., d, d)`` for ``emitter_m``
    of shape ``(..., d)`` (many emitter positions in one call: a geometry map).

    With ``data.unknowns`` (or ``unknowns``) it is the information left for the position once
    the nuisance parameters are estimated too, the Schur complement of MATH §15; pass
    ``unknowns=()`` for the bound with them known (the price of an unknown is the ratio).
    """
    return gram_information(whitened_jacobian(data, emitter_m, modalities, unknowns=unknowns))


def fisher_information_per_frame(
    data: MeasurementSet,
    emitter_m: ArrayLike,
    modalities: str | Iterable[str] = "toa+doppler",
    *,
    unknowns: Iterable[str] | None = None,
) -> tuple[FloatArray, FloatArray]:
    """Information of each frame and accumulated up to each frame (MATH §8, §15).

    Returns ``(per_frame, accumulated)``, each of shape ``(n_frames, ..., d, d)`` for
    ``emitter_m`` of shape ``(..., d)``, frames in the order of ``data.frames``;
    ``per_frame[l]`` is :func:`fisher_information` of frame ``l``'s samples and
    ``accumulated[l]`` that of the samples of frames ``<= l``: the running sum
    ``Σ_{l' ≤ l} per_frame[l']`` for a cooperative emitter. With nuisance parameters
    (``unknowns``, default ``data.unknowns``) one δ and one b are shared by the samples of
    frames ``<= l``, so the accumulated information is not that sum. Both come from
    :func:`frame_statistics`, which gives the information of any other set of frames too.
    """
    statistics = frame_statistics(data, emitter_m, modalities, unknowns=unknowns)
    return statistics.per_group(), statistics.accumulated()


@dataclass(frozen=True, slots=True, eq=False)
class InformationStatistics:
    r"""What the information of any union of groups of samples needs (MATH §8, §15).

    The samples are split into ``G`` groups (a measurement set's frames, a planned frame).
    With ``g`` the rows ``∇h_k/σ`` of :func:`whitened_gradients` (uncentred), per group:

    Attributes
    ----------
    plain : (G, ..., d, d)
        ``Σ g gᵀ`` over the group's rows of the modalities whose nuisance parameters are known
        (one Gram matrix of their rows, in modality order).
    centred : (C, G, ..., d, d)
        Per modality with an unknown nuisance parameter (``C`` of them, in modality order),
        ``Σ (g − ḡ)(g − ḡ)ᵀ`` over the group's rows, ``ḡ`` their mean in the group.
    mean : (C, G, ..., d)
        ``ḡ`` of those rows in each group.
    count : (G,)
        The samples of each group (one row per sample and modality).
    prior : (..., d, d)
        The information of the terrain prior (MATH §8, :func:`terrain_row`), added once to
        that of any set of groups (zeros: none).

    The information of a union ``S`` of groups, with one nuisance parameter per centred
    modality shared by all of ``S``'s samples, is the plain part plus the scatter of the
    centred rows about their mean over ``S``, within the groups and between them:

    .. math::

        J_S = \sum_{G \in S} \text{plain}_G + \sum_{\text{centred}} \Big( \sum_{G \in S}
              \text{centred}_G + \sum_{G \in S} n_G (\bar g_G - \bar g_S)(\bar g_G - \bar g_S)^\top
              \Big),\qquad \bar g_S = \frac{\sum_G n_G \bar g_G}{\sum_G n_G},

    which is ``Σ g gᵀ − (Σ g)(Σ g)ᵀ / n`` over ``S``'s rows, formed without its cancellation,
    plus ``prior``.
    """

    plain: FloatArray
    centred: FloatArray
    mean: FloatArray
    count: FloatArray
    prior: FloatArray | None = None

    @property
    def n_groups(self) -> int:
        return len(self.count)

    @property
    def dimension(self) -> int:
        """``d``: the coordinates of the position the information is of."""
        return int(self.plain.shape[-1])

    def information(self, groups: ArrayLike | None = None) -> FloatArray:
        """``J`` of the union of ``groups`` (group indices, repeats ignored; None: every
        group), with the nuisance parameters shared over it, plus the terrain prior's
        (``prior``), shape ``(..., d, d)``. No group: the prior's alone (zeros without one)."""
        index = (
            np.arange(self.n_groups)
            if groups is None
            else np.unique(np.asarray(groups, dtype=np.int64).reshape(-1))
        )
        information = self.plain[index].sum(axis=0)
        if self.prior is not None:
            information = information + self.prior
        counts = self.count[index]
        total = counts.sum()
        if total == 0:
            return information
        weights = counts.reshape((-1,) + (1,) * (self.mean.ndim - 2))
        for centred, mean in zip(self.centred[:, index], self.mean[:, index], strict=True):
            pooled = (weights * mean).sum(axis=0) / total
            offset = mean - pooled
            between = np.einsum("g,g...i,g...j->...ij", counts, offset, offset)
            information = information + (centred.sum(axis=0) + between)
        return information

    def per_group(self) -> FloatArray:
        """``J`` of each group alone, shape ``(G, ..., d, d)``."""
        return np.stack([self.information([g]) for g in range(self.n_groups)])

    def accumulated(self) -> FloatArray:
        """``J`` of groups ``0 … l`` for each ``l``, shape ``(G, ..., d, d)``."""
        return np.stack([self.information(np.arange(g + 1)) for g in range(self.n_groups)])

    def joined(self, other: InformationStatistics) -> InformationStatistics:
        """The groups of ``self`` then those of ``other``, their leading axes broadcast
        together (past frames at ``(n_c, 1)`` candidates, a planned frame at ``(n_c, n_ψ)``);
        the terrain prior is ``self``'s (one prior however many sets of samples)."""
        if len(self.centred) != len(other.centred):
            raise ValueError(
                "statistics: the two sets centre different modalities; build both with the "
                "same modalities and unknowns"
            )
        leading = np.broadcast_shapes(self.plain.shape[1:-2], other.plain.shape[1:-2])

        def joined(a: FloatArray, b: FloatArray, axis: int, tail: int) -> FloatArray:
            def shape(x: FloatArray) -> tuple[int, ...]:
                return (*x.shape[: axis + 1], *leading, *x.shape[x.ndim - tail :])

            return np.concatenate(
                [np.broadcast_to(a, shape(a)), np.broadcast_to(b, shape(b))], axis=axis
            )

        return InformationStatistics(
            plain=joined(self.plain, other.plain, 0, 2),
            centred=joined(self.centred, other.centred, 1, 2),
            mean=joined(self.mean, other.mean, 1, 1),
            count=np.concatenate([self.count, other.count]),
            prior=None
            if self.prior is None
            else np.broadcast_to(self.prior, (*leading, self.dimension, self.dimension)),
        )


def information_statistics(
    position_m: ArrayLike,
    velocity_mps: ArrayLike,
    emitter_m: ArrayLike,
    data: MeasurementSet,
    modalities: str | Iterable[str] = "toa+doppler",
    *,
    unknowns: Iterable[str] = (),
    groups: ArrayLike | None = None,
) -> InformationStatistics:
    """The :class:`InformationStatistics` of the given samples (MATH §8, §15).

    Arguments as for :func:`whitened_gradients`; ``groups`` gives each of the ``N`` samples
    its group's label (the groups are the distinct labels, ascending); None puts every sample
    in one group. A modality whose nuisance parameter is in ``unknowns`` is kept centred per
    group; the others' rows go into one Gram matrix per group. With the height in ``unknowns``
    and a terrain in ``data`` the prior's information is kept apart (:func:`terrain_row`).
    """
    chosen = parse_modalities(modalities)
    blocks = _whitened_blocks(position_m, velocity_mps, emitter_m, data, chosen)
    centred_modalities = {AFFECTED_MODALITY[name] for name in nuisance_unknowns(unknowns)}
    n = blocks[0].shape[-2]
    labels = np.zeros(n, dtype=np.int64) if groups is None else np.asarray(groups).reshape(-1)
    if len(labels) != n:
        raise ValueError(f"groups: expected one label per sample ({n}), got {len(labels)}")
    members = [labels == label for label in np.unique(labels)]
    plain_blocks = [b for m, b in zip(chosen, blocks, strict=True) if m not in centred_modalities]
    centred_blocks = [b for m, b in zip(chosen, blocks, strict=True) if m in centred_modalities]
    leading, d = blocks[0].shape[:-2], blocks[0].shape[-1]
    plain = np.stack(
        [
            gram_information(np.concatenate([b[..., member, :] for b in plain_blocks], axis=-2))
            if plain_blocks
            else np.zeros((*leading, d, d))
            for member in members
        ]
    )
    centred = np.zeros((len(centred_blocks), len(members), *leading, d, d))
    mean = np.zeros((len(centred_blocks), len(members), *leading, d))
    for c, block in enumerate(centred_blocks):
        for g, member in enumerate(members):
            rows = block[..., member, :]
            mean[c, g] = rows.mean(axis=-2)
            centred[c, g] = gram_information(rows - mean[c, g][..., None, :])
    count = np.array([np.count_nonzero(member) for member in members], dtype=float)
    row = terrain_row(data, emitter_m, unknowns)
    prior = None if row is None else np.broadcast_to(gram_information(row), (*leading, d, d))
    return InformationStatistics(plain=plain, centred=centred, mean=mean, count=count, prior=prior)


def frame_statistics(
    data: MeasurementSet,
    emitter_m: ArrayLike,
    modalities: str | Iterable[str] = "toa+doppler",
    *,
    unknowns: Iterable[str] | None = None,
) -> InformationStatistics:
    """:func:`information_statistics` of ``data``'s samples, one group per frame in the order
    of ``data.frames`` (MATH §8, §15): ``.information(frames)`` is ``J`` of those frames'
    samples with one δ and one b shared by all of them (``unknowns``, default
    ``data.unknowns``), ``.accumulated()`` and ``.per_group()`` those of every frame so far
    and of each frame alone."""
    unknowns = data.unknowns if unknowns is None else unknowns
    return information_statistics(
        data.position_m,
        data.velocity_mps,
        emitter_m,
        data,
        modalities,
        unknowns=unknowns,
        groups=data.frame,
    )


def regular_symmetric(matrix: ArrayLike) -> BoolArray:
    """Where symmetric matrices ``(..., d, d)`` are regular, shape ``(...)``: the one rule of
    regularity of the bound (MATH §8), ``det J > SINGULAR_RTOL · |Π_i J_ii|``
    (:data:`SINGULAR_RTOL`). A NaN or ``inf`` entry or a negative determinant counts as
    singular. ``d = 2`` is :func:`regular_2x2`, the determinant in closed form."""
    J = np.asarray(matrix, dtype=float)
    if J.shape[-1] == 2:
        return regular_2x2(J)
    regular = np.zeros(J.shape[:-2], dtype=bool)
    finite = np.isfinite(J).all(axis=(-2, -1))
    if finite.any():
        kept = J[finite]
        diagonal = np.abs(np.prod(np.diagonal(kept, axis1=-2, axis2=-1), axis=-1))
        regular[finite] = np.linalg.det(kept) > SINGULAR_RTOL * np.maximum(
            diagonal, np.finfo(float).tiny
        )
    return regular


def regular_2x2(matrix: ArrayLike) -> BoolArray:
    """Where a symmetric 2×2 matrix ``(..., 2, 2)`` is regular, shape ``(...)``: the ``d = 2``
    case of :func:`regular_symmetric`, its determinant in closed form.

    Regular: ``det > SINGULAR_RTOL · |J₁₁ J₂₂|`` (a negative determinant, NaN or ``inf``
    entries count as singular). Reads ``J₁₁``, ``J₁₂`` and ``J₂₂``.
    """
    J = np.asarray(matrix, dtype=float)
    a, b, d = J[..., 0, 0], J[..., 0, 1], J[..., 1, 1]
    det = a * d - b * b
    return det > SINGULAR_RTOL * np.maximum(np.abs(a * d), np.finfo(float).tiny)


def inverse_2x2(matrix: ArrayLike) -> FloatArray:
    """The inverse of symmetric 2×2 matrices ``(..., 2, 2)`` (an information or a covariance):
    the ``d = 2`` case of :func:`inverse_symmetric`.

    ``[[d, −b], [−b, a]] / (a d − b²)`` from ``a = J₁₁``, ``b = J₁₂``, ``d = J₂₂``; NaN where
    the matrix is singular (:func:`regular_2x2`). Applied to ``J`` it is the CRLB of MATH §8.
    """
    J = np.asarray(matrix, dtype=float)
    a, b, d = J[..., 0, 0], J[..., 0, 1], J[..., 1, 1]
    det = a * d - b * b
    with np.errstate(divide="ignore", invalid="ignore"):
        inverse = (
            np.stack([np.stack([d, -b], -1), np.stack([-b, a], -1)], -2) / det[..., None, None]
        )
    inverse[~regular_2x2(J)] = np.nan
    return inverse


def inverse_symmetric(matrix: ArrayLike) -> FloatArray:
    """The inverse of symmetric matrices ``(..., d, d)`` of any size, NaN where singular
    (:func:`regular_symmetric`): an information's is the CRLB (MATH §8), a covariance's the
    weight of the NEES (MATH §16).

    ``d = 2`` is :func:`inverse_2x2` (the closed form); a larger one is inverted by LU
    (``numpy.linalg.inv``) and made exactly symmetric, ``(A + Aᵀ)/2``.
    """
    J = np.asarray(matrix, dtype=float)
    if J.shape[-1] == 2:
        return inverse_2x2(J)
    inverse = np.full(J.shape, np.nan)
    regular = regular_symmetric(J)
    if regular.any():
        solved = np.linalg.inv(J[regular])
        inverse[regular] = 0.5 * (solved + np.swapaxes(solved, -1, -2))
    return inverse


def rmse_bound_m(information: ArrayLike) -> FloatArray:
    """``√trace(J⁻¹)`` of information ``(..., d, d)``: the RMSE bound in metres (MATH §8),
    shape ``(...)``; NaN where ``J`` is singular."""
    covariance = inverse_symmetric(information)
    return np.sqrt(np.trace(covariance, axis1=-2, axis2=-1))
