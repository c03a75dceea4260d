"""transds/1 parsing: strict, with errors that name the board, the line and the field."""

from __future__ import annotations

import math
from typing import Any

import pytest

from missing_link.descriptors import parse_transds
from missing_link.errors import DescriptorError
from missing_link.virtual.sims import thesis

SPEC_EXAMPLE = """transds/1
quad,0,quad,HEDS-6500,2,int16_t,-1,unit=count,rate_hz=100,kind=sensor
dist_ir,1,sharp,GP2Y0A02YK,8,uint16_t,0,unit=mm,ros=sensor_msgs/msg/Range
servo,2,hs645,HS-645MG,1,int8_t,-128,kind=actuator,call=a2j_set_servo
"""


def test_spec_example() -> None:
    quad, ir, servo = parse_transds(SPEC_EXAMPLE, "b")
    assert (quad.name, quad.id, quad.chan_count, quad.dtype, quad.na) == (
        "quad",
        0,
        2,
        "int16_t",
        -1,
    )
    assert quad.options == {"unit": "count", "rate_hz": "100", "kind": "sensor"}
    assert ir.options["ros"] == "sensor_msgs/msg/Range"
    assert servo.is_actuator and servo.call == "a2j_set_servo"
    assert parse_transds("transds/1\n" + "\n".join(t.line() for t in (quad, ir, servo))) == [
        quad,
        ir,
        servo,
    ]


def test_thesis_sim_descriptors_parse() -> None:
    ts = parse_transds(thesis().transds_blob().decode(), "thesis")
    assert [t.name for t in ts] == ["quad", "dist_ir", "dist_us", "servo", "trigger"]
    assert ts[2].na == 0x00FFFFFF


def test_unknown_keys_kept_and_reported() -> None:
    (t,) = parse_transds("transds/1\nx,1,p,M,1,float,nan,color=red\n")
    assert t.unknown == {"color": "red"} and math.isnan(t.na)
    assert t.decode(bytes(8) + b"\x00\x00\xc0\x7f") == [(0, None)]  # NaN is the N/A value


@pytest.mark.parametrize(
    ("line", "field", "why"),
    [
        ("Quad,0,q,M,1,int8_t,0", "name", "not a topic name"),
        ("q,240,q,M,1,int8_t,0", "id", "outside 0..239"),
        ("q,x,q,M,1,int8_t,0", "id", "not a number"),
        ("q,0,,M,1,int8_t,0", "prefix", "empty"),
        ("q,0,q,M,0,int8_t,0", "chan_count", "outside 1..255"),
        ("q,0,q,M,1,int9_t,0", "type", "not one of"),
        ("q,0,q,M,1,uint8_t,-1", "na", "outside uint8_t"),
        ("q,0,q,M,1,int8_t", "na", "missing"),
        ("q,0,q,M,22,uint32_t,0", "chan_count", "one SIF carries at most 255"),
        ("q,0,q,M,1,int8_t,0,kind=motor", "kind", "not sensor or actuator"),
        ("q,0,q,M,1,int8_t,0,kind=actuator", "call", "actuator needs"),
        ("q,0,q,M,1,int8_t,0,rate_hz=fast", "rate_hz", "not a number"),
        ("q,0,q,M,1,int8_t,0,ros=Range", "ros", "not a message type"),
        ("q,0,q,M,1,int8_t,0,unit", "unit", "key=value"),
    ],
)
def test_bad_lines_name_line_and_field(line: str, field: str, why: str) -> None:
    with pytest.raises(DescriptorError) as err:
        parse_transds("transds/1\n" + line + "\n", "myboard")
    msg = str(err.value)
    assert msg.startswith("myboard: transds line 2, field " + field), msg
    assert why in msg


def test_duplicates_and_header() -> None:
    with pytest.raises(DescriptorError, match="line 3, field id: 0 already on line 2"):
        parse_transds("transds/1\na,0,p,M,1,int8_t,0\nb,0,p,M,1,int8_t,0\n")
    with pytest.raises(DescriptorError, match="line 3, field name"):
        parse_transds("transds/1\na,0,p,M,1,int8_t,0\na,1,p,M,1,int8_t,0\n")
    with pytest.raises(DescriptorError, match="line 1: expected 'transds/1'"):
        parse_transds("transds/2\n")


def test_decode_rejects_wrong_size() -> None:
    (t,) = parse_transds("transds/1\nx,1,p,M,2,int16_t,-1\n")
    with pytest.raises(ValueError, match="expected 20"):
        t.decode(b"\x00" * 19)


def test_toml_descriptors_for_original_boards(tmp_path: Any) -> None:
    from missing_link.descriptors import load_descriptor_file

    (t,) = load_descriptor_file("examples/original-board.toml")
    assert (t.name, t.id, t.dtype, t.na, t.unit) == ("quad", 13, "int16_t", -1, "count")
    bad = tmp_path / "bad.toml"
    bad.write_text(
        '[[transducer]]\nname="a"\nid=1\nprefix="p"\nmodel="M"\nchan_count=1\ntype="int8_t"\nna=0\n'
        '[[transducer]]\nname="b"\nid=2\nprefix="p"\nmodel="M"\nchan_count=1\ntype="int8_t"\nna=300\n'
    )
    with pytest.raises(DescriptorError) as err:
        load_descriptor_file(str(bad))
    assert str(err.value).startswith(f"{bad}: [[transducer]] #2, field na: '300'")
    bad.write_text('[[transducer]]\nname="a"\n')
    with pytest.raises(DescriptorError, match=r"#1 \(a\): missing id, prefix"):
        load_descriptor_file(str(bad))
    bad.write_text("[[transducer]\n")
    with pytest.raises(DescriptorError, match="not valid TOML"):
        load_descriptor_file(str(bad))
    with pytest.raises(DescriptorError, match="cannot read"):
        load_descriptor_file(str(tmp_path / "none.toml"))
