"""An identification source into the core, recognised by its look: a measurement CSV with its
YAML sidecar, a MUKCa folder, a recorded session (bag) or a collection folder.

:func:`recognise` says which of the four a path is (ValueError listing what it looked for,
for anything else); :func:`load_source` reads it into what the identification engine takes:
measurements with the arm's model (a measurement file, a MUKCa folder), or the cell's
observations with the cell (a bag, a collection), and where they came from.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

MEASUREMENT_FILE, MUKCA, BAG, COLLECTION = 'measurement file', 'MUKCa folder', 'bag', \
    'collection'
KINDS = (MEASUREMENT_FILE, MUKCA, BAG, COLLECTION)
LOOKED_FOR = ('a measurement CSV with its sidecar (NAME.csv + NAME.yaml)',
              'a MUKCa folder (<location>/hole_0.csv)', 'a bag (metadata.yaml or *.mcap)',
              'a collection folder (collection.json, or collection.yaml of older versions)')


def recognise(path: str | Path) -> str:
    """Which of :data:`KINDS` ``path`` is; ValueError naming what it looked for otherwise."""
    path = Path(path).expanduser()
    if path.is_file():
        return MEASUREMENT_FILE           # the sidecar is checked when it is read
    if path.is_dir():
        if any(path.glob('*/hole_0.csv')):
            return MUKCA
        if (path / 'metadata.yaml').is_file() or any(path.glob('*.mcap')):
            return BAG
        if _is_collection(path):
            return COLLECTION
        what = 'a folder that is none of the sources'
    else:
        what = 'no such file or folder'
    raise ValueError(f'{path}: {what}; looked for {", ".join(LOOKED_FOR[:-1])} or '
                     f'{LOOKED_FOR[-1]}')


@dataclass(frozen=True)
class Source:
    """What a source gives the engine. A measurement file or MUKCa folder: ``file`` (its
    measurements, q in the file's joint order: ``file.in_joint_order`` gives the model's). A bag or a collection: ``observations`` of
    ``cell``'s spheres (or a laser tracker's points), joints in ``model``'s order.
    ``provenance``: where they came from (JSON-ready)."""

    kind: str
    path: Path
    model: Any                        # core.kinematics.model.KinematicModel
    file: Any = None                  # loaders.measurements.MeasurementFile
    observations: Any = None          # SphereObservations | PositionObservations
    cell: Any = None                  # core.cell.Cell
    description: Any = None           # core UrdfRobot of a measurement file's URDF (None: DH)
    provenance: dict = field(default_factory=dict)

    @property
    def rows(self) -> int:
        return len(self.file.measurements) if self.file is not None else \
            len(self.observations.q)


def load_source(path: str | Path, *, cell=None, urdf: str | None = None,
                base_link: str | None = None, tip_link: str | None = None,
                dh: str | None = None, ball=(0.0, 0.0, 0.04)) -> Source:
    """The :class:`Source` at ``path``. A measurement file or MUKCa folder: its arm from
    ``dh`` or ``urdf`` (base and tip links default to the sidecar's frames; a MUKCa folder:
    iiwa14.urdf beside it), ``ball`` the MUKCa ball's nominal centre in the tip [m]. A bag or a
    collection: ``cell`` (core.cell.Cell) is its robot. ValueError (one line) for anything
    that cannot be read; BagError for an unreadable bag."""
    from cobot_calib_ros.loaders import measurements
    path = Path(path).expanduser()
    kind = recognise(path)
    if kind in (MEASUREMENT_FILE, MUKCA):
        file = measurements.load_socket_measurements(path, ball) if kind == MUKCA else \
            measurements.load_measurements(path)
        model = measurements.robot_model(path, file.frames, urdf, base_link, tip_link, dh)
        description = None if dh else measurements.robot_description(
            path, file.frames, urdf, base_link, tip_link)
        return Source(kind, path, model, file=file, description=description,
                      provenance={'source': file.source, 'source_kind': kind,
                                  'frames': file.frames})
    from cobot_calib_ros.core.kinematics import model_for
    if cell is None:
        raise ValueError(f'{path}: a {kind} is identified on its cell; give the cell')
    model = model_for(cell)
    if kind == BAG:
        from cobot_calib_ros.bags.sphere_captures import sphere_observations
        data, _ = sphere_observations(path, cell, model)
        return Source(kind, path, model, observations=data, cell=cell,
                      provenance={'source': str(path), 'source_kind': kind, 'cell': cell.name})
    return of_collection(load_collection_folder(path), cell, model, path)


def of_collection(collection, cell, model, path: Path | None = None) -> Source:
    """A stored collection (store.collections.Collection) of ``cell``'s robot as a
    :class:`Source`: its observations, how partial it is and its planning in the provenance.
    ValueError for another robot's or one that holds too little."""
    meta = collection.meta
    if meta['robot'] != cell.robot:
        raise ValueError(f'collection {meta["id"]} is of a {meta["robot"]}, this cell is a '
                         f'{cell.robot}')
    partial = partial_note(collection)
    try:
        data = observations(collection)
    except ValueError as e:
        raise ValueError('; '.join(filter(None, (str(e), partial)))) from None
    provenance = {'source': str(path or meta['id']), 'source_kind': COLLECTION,
                  'cell': cell.name, 'collection': meta['id'], 'partial': partial}
    if meta.get('planning') is not None:
        provenance['planning'] = {'collection': meta['id'], **{
            k: v for k, v in meta['planning'].items() if k != 'task_q'}}
    return Source(COLLECTION, Path(path or meta['id']), model, observations=data, cell=cell,
                  provenance=provenance)


def observations(collection):
    """The core's observations of a stored collection (relative for spheres, absolute for a
    laser tracker); ValueError if it holds too little."""
    from cobot_calib_ros.core.kinematics.identification.observations import (
        PositionObservations, SphereObservations)
    meta = collection.meta
    if meta['source'] == 'spheres':
        return SphereObservations(collection.q, collection.target,
                                  tuple(tuple(d) for d in meta['known_distances']))
    return PositionObservations(collection.q, collection.p)


def partial_note(collection) -> str:
    """'' for a complete collection, else how many poses it lacks and how to resume it."""
    planning = collection.meta.get('planning')      # a planned collection: up to max_poses
    planned = planning['settings']['max_poses'] if planning else len(collection.meta['plan'])
    visited = len(collection.q) + len(collection.skipped)
    if collection.meta['status'] == 'done' or visited >= planned:
        return ''
    name = collection.meta['id']
    how = f'cobot-calib identify --resume {name}' if collection.meta['source'] == 'spheres' \
        else f'collect_sphere_data with collection_id {name}'
    return (f'collection {name} is partial: {visited} of {planned} poses visited '
            f'({planned - visited} missing; {len(collection.q)} measured); resume it with {how}')


def _is_collection(path: Path) -> bool:
    """Whether folder ``path`` holds a collection's metadata (store.collections' file)."""
    from cobot_calib_ros.store.collections import CollectionStore
    return CollectionStore.meta_path(path).is_file()


def load_collection_folder(folder: str | Path):
    """A collection folder given by path (one with collection.json and rows.csv)."""
    from cobot_calib_ros.store.collections import CollectionStore
    path = Path(folder).expanduser().resolve()
    if not _is_collection(path):
        raise ValueError(f'{path}: not a collection folder (no collection.json); give a folder '
                         'written by collect_sphere_data')
    folder_store = CollectionStore.of_folder(path.parent)
    data = folder_store.load(path.name)
    if data is None:
        raise ValueError(f'{path}: unreadable collection: {folder_store.meta_problem(path.name)}')
    return data
