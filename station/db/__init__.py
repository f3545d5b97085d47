"""The results database behind station/results_db.py: SQLAlchemy schema, alembic migrations,
store-and-forward to a line's central database, yields, and the MES export."""
