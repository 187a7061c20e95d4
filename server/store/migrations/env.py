"""Alembic's environment for gyrocal's store: migrations run on the connection ``server.store.schema`` hands
over (in its transaction, under its lock), never on one of their own."""

from alembic import context

from server.store.tables import Base

connection = context.config.attributes["connection"]
context.configure(connection=connection, target_metadata=Base.metadata)
with context.begin_transaction():
    context.run_migrations()
