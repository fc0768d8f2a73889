"""The laser-tracer multi-station method (seed 000): everything that is this method's.

Its folder takes rtcal from ``rtcal.api`` (and ``rtcal.solvers``) as a plugin does, but for what a plugin would not
need (tests/test_api.py lists each such import, so a new one fails until it is taken from the face or listed with
its reason):

- ``method.py``: the seed's own simulation — its instruments on rtcal's concrete bench (``simulators.bench``,
  ``simulators.instruments``), the bench's truth (``simulators.truth``) and the Monte Carlo's draws of the
  scenario's terms (``simulators.scenario``); a plugin's kind brings its own simulation through ``SimBench``.
  ``drivers.factory``'s typed openers (the stage's limits, the CMM's volume and tool), which the face's generic
  ``open_instrument`` does not take. ``rtcal.results.model`` as ``rm``: the estimate blocks below.
- ``results.py``, ``outputs.py``, ``method.py``: its estimate blocks (``NetworkEstimate``, ``PaperEstimate``,
  ``SharedDeadPathEstimate``, ``StationChainEstimate``, ``AxisLocation``, ``ErrorMotionTarget``, ``AXIS_CONVENTION``,
  …) stay in the shared model (rtcal/results/model.py); they are this method's words,
  not a plugin's (a plugin declares its blocks in its own results module, as rtcal.methods.rtest does). They
  could move into this folder with a shim (as ``MultistationEstimator`` did); not done yet.
- ``outputs.py``: the certificate's ``largest`` (two lines, not worth a public name).
- ``design.py``: ``rtcal plan --optimize``'s design of CMM points is a command's work, not a method's plan or
  analysis: it reads a run's store (``RunStore``), writes the procedure's YAML and a bench beside it
  (``rtcal.procedure.yamlfile``, ``rtcal.outputs``, ``rtcal.methods.planner.keep_bench``).
"""
