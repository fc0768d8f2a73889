"""A lab's catalogue of calibrations (``rtcal catalog``): each finished, verified run one entry in
a database (SQLite by default, PostgreSQL for a fleet), and a machine axis's history from them."""
