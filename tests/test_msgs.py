"""Message generation from descriptors: .msg text, packages, typestore registration, and the
fast CDR encoder checked byte for byte against rosbags' serializer."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from rosbags.typesys import Stores, get_typestore

from missing_link.board.dtypes import DTYPES
from missing_link.descriptors import Transducer, parse_transds
from missing_link.ros.msgs import (
    ROS_TYPES,
    CdrEncoder,
    msg_name,
    msg_text,
    package_files,
    register_types,
    type_name,
)
from missing_link.virtual.sims import thesis

THESIS = parse_transds(thesis().transds_blob().decode())


def test_names_and_text() -> None:
    assert [msg_name(t) for t in THESIS] == ["Quad", "DistIr", "DistUs", "Servo", "Trigger"]
    ir = THESIS[1]
    text = msg_text(ir, 2)
    assert text.endswith("builtin_interfaces/Time[] times\nuint16[] values\n")
    assert msg_text(ir, 1).endswith("time[] times\nuint16[] values\n")
    assert "GP2Y0A02YK" in text and "unit mm" in text


def test_package_skeletons() -> None:
    ros2 = package_files(THESIS, "robot_msgs", 2)
    assert set(ros2) == {f"msg/{msg_name(t)}.msg" for t in THESIS} | {
        "package.xml",
        "CMakeLists.txt",
    }
    assert "rosidl_generate_interfaces" in ros2["CMakeLists.txt"]
    assert '"msg/DistIr.msg"' in ros2["CMakeLists.txt"]
    assert "<member_of_group>rosidl_interface_packages</member_of_group>" in ros2["package.xml"]
    ros1 = package_files(THESIS, "robot_msgs", 1)
    assert "add_message_files" in ros1["CMakeLists.txt"] and "catkin" in ros1["package.xml"]
    with pytest.raises(ValueError, match="package name"):
        package_files(THESIS, "Robot-Msgs")


@pytest.mark.parametrize("distro", [Stores.ROS2_HUMBLE, Stores.ROS2_JAZZY])
def test_registered_types_have_stable_definitions(distro: Stores) -> None:
    store = get_typestore(distro)
    names = register_types(store, THESIS)
    assert names[0] == "missing_link_msgs/msg/Quad"
    text, _md5 = store.generate_msgdef(names[1], ros_version=2)
    assert text.startswith("builtin_interfaces/Time[] times\nuint16[] values\n")
    assert store.hash_rihs01(names[1]).startswith("RIHS01_")


STORE = get_typestore(Stores.ROS2_JAZZY)


def values_for(dtype: str) -> st.SearchStrategy[object]:
    if dtype == "float":
        return st.floats(width=32, allow_nan=False)
    if dtype == "double":
        return st.floats(allow_nan=False)
    if dtype == "bool":
        return st.integers(0, 1)
    _c, _s, lo, hi = DTYPES[dtype]
    return st.integers(lo, hi)


@settings(max_examples=150, deadline=None)
@given(st.data())
def test_cdr_encoder_matches_rosbags(data: st.DataObject) -> None:
    dtype = data.draw(st.sampled_from(sorted(DTYPES)))
    n = data.draw(st.integers(1, 255 // (8 + DTYPES[dtype][1])))
    na = data.draw(values_for(dtype))
    t = Transducer(f"t_{dtype}", 1, "p", "M", n, dtype, na)  # type: ignore[arg-type]
    register_types(STORE, [t])
    stamps = data.draw(st.lists(st.integers(0, (2**31 - 1) * 10**9), min_size=n, max_size=n))
    values = data.draw(st.lists(st.none() | values_for(dtype), min_size=n, max_size=n))
    ours = CdrEncoder(t).encode(stamps, values)
    name = type_name(t)
    cls = STORE.types[name]
    time_cls = STORE.types["builtin_interfaces/msg/Time"]
    arr = [na if v is None else v for v in values]
    np_type = {"float32": np.float32, "float64": np.float64, "bool": np.bool_}.get(
        ROS_TYPES[dtype], getattr(np, ROS_TYPES[dtype], None)
    )
    msg = cls(
        times=[time_cls(sec=s // 10**9, nanosec=s % 10**9) for s in stamps],
        values=np.array(arr, dtype=np_type),
    )
    assert ours == bytes(STORE.serialize_cdr(msg, name))
    back = STORE.deserialize_cdr(ours, name)
    assert [x.sec * 10**9 + x.nanosec for x in back.times] == stamps


def test_nan_na_survives() -> None:
    (t,) = parse_transds("transds/1\nx,1,p,M,2,float,nan\n")
    out = CdrEncoder(t).encode([0, 5], [None, 1.5])
    back = STORE.deserialize_cdr(out, register_types(STORE, [t])[0])
    assert math.isnan(back.values[0]) and back.values[1] == 1.5
