"""results.json as one typed model: the classes (:mod:`rtcal.results.model`), and reading,
writing and the JSON Schema (:mod:`rtcal.results.io`)."""

from rtcal.results.io import ResultsError, parse_results, read_results, results_schema, write_results
from rtcal.results.model import SCHEMA_VERSION, RunResults

__all__ = ["SCHEMA_VERSION", "ResultsError", "RunResults", "parse_results", "read_results", "results_schema", "write_results"]
