"""A run's store: every reading and event as taken (SQLite), what a damaged one still holds, and the one resume hint."""
