"""A small ScenarioNet scenario made in code, for the reader's tests."""
import pickle

import numpy as np


def scenario(steps=4, **change):
    def track(kind="VEHICLE"):
        return {"type": kind, "state": {
            "position": np.zeros((steps, 3)), "heading": np.zeros(steps), "velocity": np.zeros((steps, 2)),
            "valid": np.ones(steps), "length": np.full((steps, 1), 4.5), "width": np.full((steps, 1), 2.0),
            "height": np.full((steps, 1), 1.5)}}

    data = {"id": "s1", "version": "x", "length": steps,
            "metadata": {"sdc_id": "ego", "ts": np.arange(steps) * 0.1, "sample_rate": 0.1, "dataset": "test"},
            "tracks": {"ego": track(), "car": track(), "cone": track("TRAFFIC_CONE")},
            "map_features": {"lane_1": {"type": "LANE_SURFACE_STREET", "polyline": np.array([[0.0, 0], [10, 0]]),
                                        "polygon": np.array([[0.0, -2], [10, -2], [10, 2], [0, 2]])},
                             "stop": {"type": "STOP_SIGN", "position": np.array([5.0, 2.0, 0.0])},
                             "walk": {"type": "CROSSWALK", "polygon": np.array([[4.0, -2], [5, -2], [5, 2]])}},
            "dynamic_map_states": {"tl": {"lane": "lane_1", "state": {"object_state": ["LANE_STATE_GO"] * steps},
                                          "stop_point": np.array([9.0, 0.0, 0.0])}}}
    for keypath, value in change.items():
        *outer, last = keypath.split("__")
        target = data
        for key in outer:
            target = target[key]
        target[last] = value
    return data


def write(tmp_path, data, name="sd_test.pkl"):
    path = tmp_path / name
    path.write_bytes(pickle.dumps(data, protocol=4))
    return path


#: a value to put where a crafted value goes (see write_crafted)
SPLICE = "SPLICE-HERE"


def deep_list(depth):
    """Pickle opcodes of a list ``depth`` levels deep ([[[...]]]), which pickle.dumps cannot write."""
    return pickle.EMPTY_LIST * depth + pickle.APPEND * (depth - 1)


def write_crafted(tmp_path, data, opcodes, name="sd_test.pkl"):
    """``data`` pickled with ``opcodes`` in place of the value SPLICE (protocol 3: no frames to mend)."""
    raw = pickle.dumps(data, protocol=3)
    marker = pickle.BINUNICODE + len(SPLICE).to_bytes(4, "little") + SPLICE.encode()
    assert raw.count(marker) == 1
    path = tmp_path / name
    path.write_bytes(raw.replace(marker, opcodes))
    return path
