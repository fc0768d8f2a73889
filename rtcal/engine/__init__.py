"""The run engine: plans of declarative steps (:mod:`.steps`, :mod:`.plan`), one :class:`~.engine.Engine`
that executes any plan under the fault policies (:mod:`.faults`) and reads every instrument through its
described values, the checks of motion (:mod:`.checks`), the operator (:mod:`.operator`), its subscribers
(:mod:`.subscribers`) and the walker that times a plan without instruments (:mod:`.walk`)."""
