"""The run machinery: a procedure run or resumed end to end, its directory, its store, its dataset."""
