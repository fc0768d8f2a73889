"""The order of work: motions, settle times, readings written to the store before the next motion."""
