"""PointCloud2 layout checks: data that does not match height x row_step is refused with the numbers."""
from __future__ import annotations

import numpy as np
import pytest

from pytest_driveeval.io.t4.pcd import read_pcd
from pytest_driveeval.io.ros.pointcloud2 import Field, PointCloud2Error, decode_pointcloud2


class Msg:
    def __init__(self, **kw):
        self.__dict__.update(kw)


def cloud_msg(height=2, width=3, point_step=12, row_step=36, extra=b""):
    data = np.arange(height * row_step // 4, dtype="<f4").view(np.uint8)
    return Msg(height=height, width=width, point_step=point_step, row_step=row_step, is_bigendian=False,
               data=np.concatenate([data, np.frombuffer(extra, np.uint8)]),
               fields=[Field("x", 0, 7), Field("y", 4, 7), Field("z", 8, 7)])


def test_a_consistent_cloud_decodes():
    assert decode_pointcloud2(cloud_msg())["x"].tolist() == [0, 3, 6, 9, 12, 15]


def test_a_layout_seen_before_decodes_the_same_and_its_errors_name_each_message():
    """Each layout's dtype is built once (pointcloud2._DTYPES); what decides the dtype is in the key."""
    first, again = cloud_msg(), cloud_msg()
    assert decode_pointcloud2(first).dtype is decode_pointcloud2(again).dtype
    again.is_bigendian = True
    assert decode_pointcloud2(again)["x"].dtype == ">f4" and decode_pointcloud2(first)["x"].dtype == "<f4"
    again.is_bigendian, again.fields = False, [Field("x", 0, 7), Field("y", 4, 7), Field("z", 8, 7, 2)]
    with pytest.raises(PointCloud2Error, match="exceeds point_step"):
        decode_pointcloud2(again)
    for index in (5, 6):  # a bad layout is refused every time, naming its message
        bad = cloud_msg()
        bad.fields = [Field("x", 0, 7), Field("x", 4, 7)]
        with pytest.raises(PointCloud2Error, match=rf"^b\.db3 /p message #{index}: duplicate field name 'x'"):
            decode_pointcloud2(bad, where=f"b.db3 /p message #{index}")


def test_more_rows_than_height_are_counted():
    msg = cloud_msg(height=3)
    msg.height = 2  # the data holds a third row
    with pytest.raises(PointCloud2Error, match=r"^b\.db3 /p message #4: data has 108 bytes, the layout needs 72 "
                                               r"\(height 2 x row_step 36\): 1 row\(s\) more than height 2$"):
        decode_pointcloud2(msg, where="b.db3 /p message #4")


def test_stray_bytes_after_the_last_row():
    with pytest.raises(PointCloud2Error, match=r"data has 77 bytes, the layout needs 72 \(height 2 x row_step 36\): "
                                               r"5 bytes too many$"):
        decode_pointcloud2(cloud_msg(extra=b"\x00" * 5))


def test_last_row_without_its_padding_is_short():
    msg = cloud_msg(row_step=40)
    msg.data = msg.data[:-4]
    with pytest.raises(PointCloud2Error, match=r"data has 76 bytes, the layout needs 80 .*: 4 bytes missing$"):
        decode_pointcloud2(msg)


def test_points_wider_than_the_row():
    with pytest.raises(PointCloud2Error, match=r"row_step 30 < width 3 x point_step 12 = 36: a row's points do "
                                               r"not fit in a row"):
        decode_pointcloud2(cloud_msg(row_step=30))


def test_an_empty_cloud_with_data_is_refused():
    msg = cloud_msg()
    msg.height, msg.width, msg.row_step = 1, 0, 0
    with pytest.raises(PointCloud2Error, match="data has 72 bytes, the layout needs 0"):
        decode_pointcloud2(msg)
    msg.data = msg.data[:0]
    assert decode_pointcloud2(msg).size == 0


def test_real_vlp16_sweep_with_an_extra_row(shared_data):
    cloud = read_pcd(shared_data / "pointclouds/vlp16_sample.pcd")  # 14,831 points x 32 bytes
    step = cloud.dtype.itemsize
    packed = np.ascontiguousarray(cloud).view(np.uint8)
    msg = Msg(height=1, width=cloud.size - 7, point_step=step, row_step=step * (cloud.size - 7),
              is_bigendian=False, data=packed,
              fields=[Field(n, cloud.dtype.fields[n][1], {"f": 7, "u": 6}[cloud.dtype[n].kind])
                      for n in ("x", "y", "z")])
    with pytest.raises(PointCloud2Error, match=rf"data has {cloud.size * step} bytes, the layout needs "
                                               rf"{(cloud.size - 7) * step} .*: {7 * step} bytes too many"):
        decode_pointcloud2(msg)
