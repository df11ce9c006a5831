"""A minimal protobuf wire-format reader and the subset of the Caffe2 schema the converter needs.

Only decoding is implemented: the converter reads NetDef files and never writes them. Field
numbers follow the public caffe2.proto (NetDef, OperatorDef, Argument, TensorProto).
"""

from __future__ import annotations

import struct
from dataclasses import dataclass, field
from pathlib import Path

VARINT, FIXED64, LENGTH, FIXED32 = 0, 1, 2, 5


class ProtobufError(ValueError):
    """The bytes are not a well-formed message of the expected kind."""


def _varint(buf: bytes, pos: int) -> tuple[int, int]:
    result = shift = 0
    while True:
        if pos >= len(buf):
            raise ProtobufError(f"truncated varint at byte {pos}")
        b = buf[pos]
        pos += 1
        result |= (b & 0x7F) << shift
        if not b & 0x80:
            return result, pos
        shift += 7
        if shift > 63:
            raise ProtobufError(f"varint longer than 10 bytes at byte {pos}")


def fields(buf: bytes) -> list[tuple[int, int, int | bytes]]:
    """Split a message into (field number, wire type, raw value) triples, in file order.

    Varints are returned as unsigned ints, fixed32/fixed64 and length-delimited
    fields as their raw bytes.
    """
    out: list[tuple[int, int, int | bytes]] = []
    pos = 0
    while pos < len(buf):
        key, pos = _varint(buf, pos)
        number, wire = key >> 3, key & 7
        if number == 0:
            raise ProtobufError(f"field number 0 at byte {pos}")
        if wire == VARINT:
            value, pos = _varint(buf, pos)
        elif wire == FIXED64:
            value, pos = buf[pos : pos + 8], pos + 8
        elif wire == FIXED32:
            value, pos = buf[pos : pos + 4], pos + 4
        elif wire == LENGTH:
            size, pos = _varint(buf, pos)
            value, pos = buf[pos : pos + size], pos + size
        else:
            raise ProtobufError(f"unsupported wire type {wire} for field {number}")
        if pos > len(buf):
            raise ProtobufError(f"field {number} runs past the end of the message")
        out.append((number, wire, value))
    return out


def _signed64(v: int) -> int:
    return v - (1 << 64) if v >= 1 << 63 else v


def _ints(wire: int, value: int | bytes) -> list[int]:
    """A repeated int field element: either one varint or a packed run of varints."""
    if wire == VARINT:
        return [_signed64(value)]  # type: ignore[arg-type]
    vals, pos = [], 0
    while pos < len(value):  # type: ignore[arg-type]
        v, pos = _varint(value, pos)  # type: ignore[arg-type]
        vals.append(_signed64(v))
    return vals


def _floats(wire: int, value: int | bytes) -> list[float]:
    """A repeated float field element: either one fixed32 or a packed run of them."""
    if wire not in (FIXED32, LENGTH) or len(value) % 4:  # type: ignore[arg-type]
        raise ProtobufError("float field with wrong wire type or length")
    return list(struct.unpack(f"<{len(value) // 4}f", value))  # type: ignore[arg-type]


def _str(value: int | bytes) -> str:
    if not isinstance(value, bytes):
        raise ProtobufError("string field is not length-delimited")
    return value.decode("utf-8")


@dataclass
class TensorProto:
    dims: list[int] = field(default_factory=list)
    data_type: int = 1
    float_data: list[float] = field(default_factory=list)
    int32_data: list[int] = field(default_factory=list)
    byte_data: bytes = b""
    name: str = ""

    @classmethod
    def parse(cls, buf: bytes) -> TensorProto:
        t = cls()
        for num, wire, val in fields(buf):
            if num == 1:
                t.dims += _ints(wire, val)
            elif num == 2:
                t.data_type = int(val)  # type: ignore[arg-type]
            elif num == 3:
                t.float_data += _floats(wire, val)
            elif num == 4:
                t.int32_data += _ints(wire, val)
            elif num == 5:
                t.byte_data = bytes(val)  # type: ignore[arg-type]
            elif num == 7:
                t.name = _str(val)
        return t


@dataclass
class Argument:
    name: str = ""
    f: float | None = None
    i: int | None = None
    s: bytes | None = None
    floats: list[float] = field(default_factory=list)
    ints: list[int] = field(default_factory=list)
    strings: list[bytes] = field(default_factory=list)
    tensors: list[TensorProto] = field(default_factory=list)

    @classmethod
    def parse(cls, buf: bytes) -> Argument:
        a = cls()
        for num, wire, val in fields(buf):
            if num == 1:
                a.name = _str(val)
            elif num == 2:
                a.f = _floats(wire, val)[0]
            elif num == 3:
                a.i = _ints(wire, val)[0]
            elif num == 4:
                a.s = bytes(val)  # type: ignore[arg-type]
            elif num == 5:
                a.floats += _floats(wire, val)
            elif num == 6:
                a.ints += _ints(wire, val)
            elif num == 7:
                a.strings.append(bytes(val))  # type: ignore[arg-type]
            elif num == 11:
                a.tensors.append(TensorProto.parse(val))  # type: ignore[arg-type]
        return a


@dataclass
class OperatorDef:
    type: str = ""
    name: str = ""
    input: list[str] = field(default_factory=list)
    output: list[str] = field(default_factory=list)
    arg: dict[str, Argument] = field(default_factory=dict)
    engine: str = ""

    @classmethod
    def parse(cls, buf: bytes) -> OperatorDef:
        op = cls()
        for num, _wire, val in fields(buf):
            if num == 1:
                op.input.append(_str(val))
            elif num == 2:
                op.output.append(_str(val))
            elif num == 3:
                op.name = _str(val)
            elif num == 4:
                op.type = _str(val)
            elif num == 5:
                a = Argument.parse(val)  # type: ignore[arg-type]
                op.arg[a.name] = a
            elif num == 7:
                op.engine = _str(val)
        return op


@dataclass
class NetDef:
    name: str = ""
    op: list[OperatorDef] = field(default_factory=list)
    external_input: list[str] = field(default_factory=list)
    external_output: list[str] = field(default_factory=list)

    @classmethod
    def parse(cls, buf: bytes) -> NetDef:
        net = cls()
        for num, _wire, val in fields(buf):
            if num == 1:
                net.name = _str(val)
            elif num == 2:
                net.op.append(OperatorDef.parse(val))  # type: ignore[arg-type]
            elif num == 7:
                net.external_input.append(_str(val))
            elif num == 8:
                net.external_output.append(_str(val))
        return net


def read_netdef(path: Path) -> NetDef:
    """Read a binary Caffe2 NetDef file; errors name the file."""
    try:
        data = Path(path).read_bytes()
    except OSError as err:
        raise ProtobufError(f"{path}: cannot read: {err}") from err
    try:
        net = NetDef.parse(data)
    except (ProtobufError, UnicodeDecodeError, struct.error) as err:
        raise ProtobufError(f"{path}: not a Caffe2 NetDef protobuf: {err}") from err
    if not net.op:
        raise ProtobufError(f"{path}: NetDef has no operators")
    return net
