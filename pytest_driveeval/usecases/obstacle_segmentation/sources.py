"""Point-cloud sources: iterables of ``(stamp_ns, frame_id, points)`` that the evaluation streams.

A source yields one cloud at a time, so a long bag never sits in memory whole.
"""
from __future__ import annotations

import os
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass

import numpy as np

from ...core.deadline import guarded_call, note
from ...core.errors import DataError
from ...io.t4.t4dataset import T4Dataset
from ...metrics.pointcloud import xyz_columns


def bag_pointclouds(dataset: T4Dataset | str | os.PathLike, topic: str) -> Iterator[tuple]:
    """Stream ``topic`` from the dataset's input_bag, one message in memory at a time."""
    from ...io.ros.rosbag import Bag

    ds = dataset if isinstance(dataset, T4Dataset) else T4Dataset(dataset)
    if ds.input_bag is None:
        raise DataError(f"t4_dataset {ds.root}: no input_bag/ folder to read {topic} from")
    with Bag(ds.input_bag) as bag:
        yield from bag.pointclouds(topic)


def sweep_pointclouds(dataset: T4Dataset | str | os.PathLike) -> Iterator[tuple]:
    """Key-frame lidar sweeps (data/LIDAR_*/*.pcd.bin) moved to base_link by their calibration."""
    ds = dataset if isinstance(dataset, T4Dataset) else T4Dataset(dataset)
    for token in ds.sample_tokens:
        rot, trans = ds.lidar_to_base_link(token)
        x, y, z = xyz_columns(ds.read_lidar(token))
        xyz = np.stack([x, y, z], axis=1).astype(np.float64) @ rot.T + trans
        yield int(ds.lidar_sample_data(token)["timestamp"]) * 1000, "base_link", xyz


def dataset_pointclouds(dataset: T4Dataset, topic: str | None) -> Iterator[tuple]:
    """The bag's topic when the dataset has an input_bag/ folder, else (or with ``topic`` None)
    its lidar sweeps."""
    if topic is None or dataset.input_bag is None:
        return sweep_pointclouds(dataset)
    return bag_pointclouds(dataset, topic)


@dataclass
class FilteredPointClouds:
    """A raw-cloud source mapped through a filter under test (raw -> obstacle points)."""

    source: Iterable[tuple]
    filter: Callable[[np.ndarray], np.ndarray]

    def __iter__(self):
        for stamp_ns, frame_id, points in self.source:
            note(**{"the point-cloud filter on the cloud stamped": f"{stamp_ns} ns"})
            yield stamp_ns, frame_id, np.asarray(guarded_call(self.filter, points))
