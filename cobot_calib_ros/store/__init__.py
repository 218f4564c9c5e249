"""Everything the suite stores: ``store.open(data_dir)`` is the one way in (store.repository).

Typed records in store.records; the database (SQLite / PostgreSQL) in store.database, .schema,
.migrations; the folder implementation in store.calibrations, .kinematics, .trials,
.collections over store.files; a cell's drift history in store.history.
"""


def open(data_dir, db=None, cell=None):   # noqa: A001 (as io.open); imported on use
    """The :class:`store.repository.Repository` of ``data_dir`` (see store.repository)."""
    from cobot_calib_ros.store.repository import open as open_repository
    return open_repository(data_dir, db, cell)
