"""The run engine: plans of steps (:mod:`.steps`, :mod:`.plan`), one :class:`~.engine.Engine` that
executes any plan under the fault policies (:mod:`.faults`), its subscribers (:mod:`.subscribers`)
and the walker that times a plan without instruments (:mod:`.walk`)."""
