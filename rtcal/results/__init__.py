"""results.json as one typed model: the classes (:mod:`rtcal.results.model`), and reading,
writing and the JSON Schema (:mod:`rtcal.results.io`, given each method's results model; the
registry of methods reads with its own: :func:`rtcal.methods.read_results`)."""

from rtcal.results.io import ResultsError, write_results
from rtcal.results.model import SCHEMA_VERSION, RunResults

__all__ = ["SCHEMA_VERSION", "ResultsError", "RunResults", "write_results"]
