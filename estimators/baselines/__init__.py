"""The linear least-squares baselines (docs/math.md §9): ``lls-toa`` on squared ranges and
``lls-rss`` on distances from received power (So & Lin). One trial at a time; each is a single
linear solve."""

from estimators.baselines.lls import LlsRss, LlsToa, solve_lls_rss, solve_lls_toa

__all__ = ["LlsRss", "LlsToa", "solve_lls_rss", "solve_lls_toa"]
