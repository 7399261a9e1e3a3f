"""Size-aware search: hit a byte budget (never above it, within a tolerance below it) with the
best fidelity the codec can reach.

    result = encode_to_budget(cloud, 5_000_000)       # .data <= 5 MB, >= 99.5 % of it

Method (MesonGS++'s, with the measured improvements noted):

* Outer loop over the reserve ratio tau (a grid).  A tau whose size range cannot contain the
  budget (even all-16-bit stays below it, or all-1-bit stays above it) is skipped, as in the
  paper; of the rest, up to ``max_candidates`` spread over the feasible range are encoded for
  real and the one with the best PSNR on **train** views wins (test views are never used).
  Then the octree depth is walked from the best (:mod:`.depth_walk`), tau refined there, and
  layer 0 re-split for layered files (:mod:`.layers`).
* Inner loop per tau (:mod:`.tau`): the SH keep-count P is chosen jointly with the bit
  allocation: for each P on a geometric grid, the bits left after geometry and SH go to the
  attribute groups by the multiple-choice-knapsack solver, and the P with the smallest total
  loss (attribute SSE Omega + SH SSE, weighted by rendering sensitivity) wins.  Rates are
  entropy-coded-size estimates per (group, bit-width) (``gsz.encoder.rate``), not q*n, so
  calibration needs few rounds.
* Calibration (:mod:`.calibration`): encode the attributes for real, measure, shift the solver
  budget by the observed error (secant steps), until the file is within ``tolerance`` below the
  target; the best file at or below the target is kept, so the result is never over budget.

Modules: ``options`` (SearchOptions, BudgetError), ``driver`` (BudgetSearch, encode_to_budget),
``tables`` (loss/rate tables, byte accounting), ``sh_model`` (SH estimates per codebook and
keep-count), ``codebooks`` (SH codebook training beside the set-up), ``tau`` (one candidate's
plan), ``calibration``, ``judge`` (train views, screening), ``sensitivity`` (channel weights),
``depth_walk``, ``layers``, ``candidate`` (Encoded, Candidate), ``report``.
"""
from .driver import BudgetSearch, encode_to_budget
from .judge import eval_cameras
from .options import SH_BITS, BudgetError, SearchOptions
from .sensitivity import channel_weights

__all__ = ["BudgetError", "BudgetSearch", "SH_BITS", "SearchOptions", "channel_weights",
           "encode_to_budget", "eval_cameras"]
