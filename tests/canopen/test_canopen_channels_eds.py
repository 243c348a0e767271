"""`sdo_servers` in the topology: validation, and the EDS lists 0x1201.. and 0x1012 as served."""

from __future__ import annotations

import canopen
import pytest
from test_eds_generation import assert_served_as_described, dcfchk, generate, topology

from fieldgate import Gateway, load_registry
from fieldgate.topology import TopologyError, load_topology


@pytest.mark.parametrize("count", [0, 129])
def test_sdo_servers_out_of_range_is_a_topology_error(tmp_path, count):
    with pytest.raises(TopologyError) as err:
        load_topology(topology(tmp_path, sdo_servers=count), load_registry())
    assert "sdo_servers" in str(err.value.issues)


async def test_eds_lists_the_extra_sdo_channels_and_time(tmp_path):
    path = generate(tmp_path, sdo_servers=3)
    eds = canopen.import_od(str(path), node_id=5)
    assert 0x1201 in eds and 0x1202 in eds and 0x1203 not in eds
    for sub in (1, 2):
        assert eds[0x1202][sub].default == 0x80000000 and eds[0x1202][sub].access_type == "rw"
    assert (
        eds[0x1201][3].data_type == canopen.objectdictionary.UNSIGNED8 and eds[0x1201][3].max == 127
    )
    assert eds[0x1200][1].default == 0x605 and eds[0x1200][1].access_type == "ro"
    assert eds[0x1012].default == 0x80000100 and eds[0x1012].access_type == "rw"
    result = dcfchk(path)
    assert result.returncode == 0 and "Warning" not in result.stderr, result.stderr
    gw = Gateway.load(topology(tmp_path, sdo_servers=3), registry=load_registry())
    await gw.start()
    try:
        assert_served_as_described(eds, gw.component("plc").node)
    finally:
        await gw.stop()
