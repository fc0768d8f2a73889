"""Alembic's environment for the catalogue: migrations run on the connection rtcal opened
(rtcal/catalog/store.py), never on a URL of their own."""

from alembic import context

connection = context.config.attributes["connection"]
context.configure(connection=connection, target_metadata=None, transactional_ddl=True)
with context.begin_transaction():
    context.run_migrations()
