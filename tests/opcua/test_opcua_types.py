"""64-bit integers, doubles and text as OPC UA variables; a value the back scaled carries its
EngineeringUnits and EURange on the variable itself (no _eng twin); a client write outside the
channel's range or length is Bad_OutOfRange before anything reaches the fieldbus side."""

from __future__ import annotations

from asyncua import ua

from fieldgate.image import ChannelSpec, DataType, Engineering, Kind, ProcessImage, Source
from fieldgate.plugins.opcua import model
from fieldgate.plugins.opcua.writes import WriteTarget, _checked

BAR = Engineering(DataType.UINT32, gain=0.01, unit="bar", low=0, high=100)


def image() -> ProcessImage:
    img = ProcessImage(clock=lambda: 0.0)
    src = Source("m", 7, 0)
    img.add(ChannelSpec("m/m7/ai0", Kind.AI, src, dtype=DataType.INT64))
    img.add(ChannelSpec("m/m7/ai1", Kind.AI, src, dtype=DataType.UINT64))
    img.add(ChannelSpec("m/m7/ai2", Kind.AI, src, dtype=DataType.STRING, length=16, label="Serial"))
    img.add(ChannelSpec("m/m7/ao0", Kind.AO, src, dtype=DataType.FLOAT64, engineering=BAR))
    img.add(ChannelSpec("m/m7/ao1", Kind.AO, src, dtype=DataType.STRING, length=4))
    return img


def test_variables_of_the_wide_types_and_units_on_the_variable():
    space = model.build("cell", list(image()), writable=["m/m7/ao*"])
    variables = {v.node_id: v for v in space.variables}
    assert variables["m/m7/ai0"].data_type == "Int64"
    assert variables["m/m7/ai1"].data_type == "UInt64"
    assert variables["m/m7/ai2"].data_type == "String"
    assert variables["m/m7/ai2"].description.startswith("Serial: ")
    setpoint = variables["m/m7/ao0"]
    assert (setpoint.data_type, setpoint.unit, setpoint.eu_range) == ("Double", "bar", (0, 100))
    assert setpoint.writable and "m/m7/ao0/eng" not in variables


def write(variant: ua.Variant) -> ua.WriteValue:
    wv = ua.WriteValue()
    wv.AttributeId = ua.AttributeIds.Value
    wv.Value = ua.DataValue(variant)
    return wv


def test_writes_outside_the_range_or_the_length_are_out_of_range():
    img = image()
    bar = WriteTarget("m/m7/ao0", ua.VariantType.Double, DataType.FLOAT64, img["m/m7/ao0"].check)
    text = WriteTarget("m/m7/ao1", ua.VariantType.String, DataType.STRING, img["m/m7/ao1"].check)
    assert _checked(write(ua.Variant(42.5, ua.VariantType.Double)), bar) == (None, 42.5)
    assert _checked(write(ua.Variant(100.5, ua.VariantType.Double)), bar)[0] == (
        ua.StatusCodes.BadOutOfRange
    )
    assert _checked(write(ua.Variant("Ü12", ua.VariantType.String)), text) == (None, "Ü12")
    assert _checked(write(ua.Variant("ABCDE", ua.VariantType.String)), text)[0] == (
        ua.StatusCodes.BadOutOfRange
    )
    assert _checked(write(ua.Variant(5, ua.VariantType.Int32)), text)[0] == (
        ua.StatusCodes.BadTypeMismatch
    )
