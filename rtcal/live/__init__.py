"""The live view and remote control of a run.

:mod:`rtcal.live.control` is the engine's control socket (pause, resume, abort with the run's
token) and its client; :mod:`rtcal.live.storeview` reads a run's store read-only into the view's
state, readings and events; :mod:`rtcal.live.server` serves the page and its API over HTTP;
:func:`rtcal.live.session.start_session` starts both for a running engine and prints the lines
`rtcal run` owes the user; :mod:`rtcal.live.commands` is `rtcal view` and `rtcal control`.
"""
