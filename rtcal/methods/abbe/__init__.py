"""The encoder Abbe-error method (seed 001) and the ISO 230-2 test: everything that is this method's.

Its folder takes rtcal from ``rtcal.api`` (and ``rtcal.solvers``) as a plugin does, but for what a plugin would not
need (tests/test_api.py lists each such import, so a new one fails until it is taken from the face or listed with
its reason):

- ``method.py``: the seed's own simulation — its instruments on rtcal's concrete bench (``simulators.bench``,
  ``simulators.instruments``) and the bench's truth (``simulators.truth``); a plugin's kind brings its own
  simulation through ``SimBench``. ``drivers.factory``'s typed openers (the stage's limits), which the face's
  generic ``open_instrument`` does not take. ``rtcal.results.model`` as ``rm``: the blocks below.
- ``results.py``, ``outputs.py``, ``method.py``: its estimate blocks (``AbbeEstimate``, ``HarmonicTerm``, …) stay in
  the shared model (rtcal/results/model.py); ``PeriodicError`` and ``PeriodicTerm`` because the shared
  ``Analysis`` declares ``periodic_error`` (ISO 230-2 Annex C). They could move into this folder with a shim (as
  ``AbbeEstimator`` did); not done yet.
- ``outputs.py``: the certificate's ``largest``, ``smallest`` (two lines each) and ``period_text`` (the
  certificate's words for a period in worm revolutions, this method's only).
"""
