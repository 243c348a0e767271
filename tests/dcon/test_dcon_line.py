"""The dcon back over a pty against the simulator: every family, formats, checksum, config checks."""

import pytest

from fieldgate import Quality

I7000 = [
    "I-7041",
    "I-7042",
    "I-7043",
    "I-7044",
    "I-7045",
    "I-7050",
    "I-7051",
    "I-7052",
    "I-7053",
    "I-7055",
    "I-7058",
    "I-7060",
    "I-7063",
    "I-7065",
    "I-7066",
    "I-7067",
    "I-7011",
    "I-7012",
    "I-7014",
    "I-7016",
    "I-7013",
    "I-7015",
    "I-7017",
    "I-7018",
    "I-7019",
    "I-7033",
    "I-7021",
    "I-7022",
    "I-7024",
]
I87K = [
    "I-87013",
    "I-87016",
    "I-87017",
    "I-87018",
    "I-87019",
    "I-87022",
    "I-87024",
    "I-87026",
    "I-87040",
    "I-87041",
    "I-87051",
    "I-87052",
    "I-87053",
    "I-87054",
    "I-87055",
    "I-87057",
    "I-87058",
    "I-87063",
    "I-87064",
    "I-87065",
    "I-87066",
    "I-87068",
    "I-87069",
]


def _stimulate(sim, gw, address, profile, phase):
    """Drive every input of a module and every output through the gateway; return what to expect."""
    expect_in, expect_out = {}, {}
    for i in range(profile.di):
        value = (i + phase) % 3 == 0
        sim.set_input(f"rs485/m{address}/di{i}", value)
        expect_in[f"rs485/m{address}/di{i}"] = value
    for i in range(profile.do):
        value = (i + phase) % 2 == 0
        gw.write(f"rs485/m{address}/do{i}", value)
        expect_out[f"rs485/m{address}/do{i}"] = value
    rng = sim.module(address).range
    for i in range(profile.ai):
        raw = rng.hmin + (rng.hmax - rng.hmin) * (i + 1 + phase) // (profile.ai + 3)
        sim.set_input(f"rs485/m{address}/ai{i}", raw)
        expect_in[f"rs485/m{address}/ai{i}"] = raw
    for i in range(profile.ao):
        raw = rng.hmin + (rng.hmax - rng.hmin) * (i + 1 + phase) // (profile.ao + 2)
        gw.write(f"rs485/m{address}/ao{i}", raw)
        expect_out[f"rs485/m{address}/ao{i}"] = raw
    return expect_in, expect_out


@pytest.mark.parametrize("models", [I7000, I87K], ids=["I-7000", "I-87K"])
async def test_every_family_reads_inputs_and_writes_outputs(gateway, models, wait_for):
    modules = [{"address": a, "model": m} for a, m in enumerate(models, 1)]
    async with gateway(modules, poll_ms=0) as gw:
        sim = gw.bench.simulator("rs485")
        back = gw.component("rs485")
        for phase in (0, 1):
            expect_in, expect_out = {}, {}
            for address in range(1, len(models) + 1):
                ins, outs = _stimulate(sim, gw, address, back.modules[address].profile, phase)
                expect_in.update(ins)
                expect_out.update(outs)
            await wait_for(
                lambda expect_in=expect_in, expect_out=expect_out: (
                    all(gw.read(c) == v for c, v in expect_in.items())
                    and all(sim.get_output(c) == v for c, v in expect_out.items())
                ),
                timeout=5,
            )
            assert all(gw.image[c].quality is Quality.GOOD for c in expect_in)
        status = gw.status()["backs"]["rs485"]
        assert status["errors"] == {} and all(m["online"] for m in status["modules"])
        assert {m["name"] for m in status["dcon_modules"]} == {
            m[2:] for m in models
        }  # identified by $AAM


@pytest.mark.parametrize("fmt", ["engineering", "percent"])
async def test_analog_values_in_engineering_and_percent_formats(gateway, fmt, wait_for):
    modules = [
        {"address": 1, "model": "I-7017", "type_code": 0x08, "data_format": fmt},
        {"address": 2, "model": "I-7024", "type_code": 0x33, "data_format": fmt},
        {"address": 3, "model": "I-7021", "type_code": 0x32, "data_format": fmt},
        {"address": 4, "model": "I-7018", "type_code": 0x0F, "data_format": fmt},
    ]
    async with gateway(modules) as gw:
        sim = gw.bench.simulator("rs485")
        sim.set_input("rs485/m1/ai0", 0x1234)
        sim.set_input("rs485/m1/ai7", -0x8000)
        sim.set_input("rs485/m4/ai3", 0x7FFF)
        gw.write("rs485/m2/ao1", -12345)
        gw.write("rs485/m3/ao0", 0x7FF)  # TV-C3: 5 V
        tolerance = 2 if fmt == "engineering" else 3  # the text's resolution (1 mV, 0.01 %)
        await wait_for(
            lambda: (
                abs(gw.read("rs485/m1/ai0") - 0x1234) <= tolerance
                and gw.read("rs485/m1/ai7") == -0x8000
                and abs(gw.read("rs485/m4/ai3") - 0x7FFF) <= tolerance
                and sim.get_output("rs485/m3/ao0") == 0x7FF
                and abs(sim.get_output("rs485/m2/ao1") + 12345) <= 4
            )
        )
        assert gw.component("rs485").modules[1].status()["data_format"] == fmt


async def test_checksum_line(gateway, wait_for):
    async with gateway(
        [{"address": 0x21, "model": "I-7055"}, {"address": 0xFF, "model": "I-7017"}], checksum=True
    ) as gw:
        sim = gw.bench.simulator("rs485")
        sim.set_input("rs485/m33/di7", True)
        gw.write("rs485/m33/do6", True)
        await wait_for(
            lambda: gw.read("rs485/m33/di7") is True and sim.get_output("rs485/m33/do6") is True
        )
        assert gw.status()["backs"]["rs485"]["errors"] == {}


async def test_module_settings_win_over_the_topology_and_mismatch_is_reported(gateway, wait_for):
    async with gateway([{"address": 1, "model": "I-7017", "type_code": 0x09}]) as gw:
        sim = gw.bench.simulator("rs485")
        sim.module(1).type_code = 0x08  # the module really is at +/-10 V
        sim.set_input("rs485/m1/ai0", 0x1000)
        await wait_for(lambda: gw.read("rs485/m1/ai0") == 0x1000)
        status = gw.component("rs485").modules[1].status()
        assert status["type_code"] == "0x08" and "topology says 0x09" in status["warnings"][0]


async def test_type_code_outside_the_model_table_is_a_config_error(gateway, wait_for):
    async with gateway([{"address": 1, "model": "I-7017"}]) as gw:
        sim = gw.bench.simulator("rs485")
        sim.module(1).type_code = 0x20  # an RTD code on an I-7017
        await wait_for(lambda: gw.image["rs485/m1/ai0"].quality is Quality.CONFIG_ERROR)
        assert "not a I-7017 range" in gw.component("rs485").modules[1].status()["config_error"]
        sim.module(
            1
        ).type_code = 0x08  # set right (DCON utility): the back sees it at the next poll
        sim.set_input("rs485/m1/ai0", 0x0100)
        await wait_for(
            lambda: (
                gw.image["rs485/m1/ai0"].quality is Quality.GOOD
                and gw.read("rs485/m1/ai0") == 0x0100
            )
        )


async def test_safe_and_power_on_values_are_stored_in_the_modules(gateway, wait_for):
    modules = [
        {"address": 1, "model": "I-7043", "safe_value": 0x00FF, "power_on_value": 0x0F00},
        {"address": 2, "model": "I-7012", "safe_value": 2, "power_on_value": 1},
        {"address": 3, "model": "I-7024", "safe_value": [100, 200, 300, 400]},
        {"address": 4, "model": "I-7021", "power_on_value": 0x400},
    ]
    async with gateway(modules) as gw:
        sim = gw.bench.simulator("rs485")
        gw.write("rs485/m1/do15", True)
        await wait_for(
            lambda: (
                sim.module(1).safe_do == 0x00FF
                and sim.module(1).power_on_do == 0x0F00
                and sim.get_output("rs485/m1/do15")
            )
        )
        await wait_for(lambda: (sim.module(2).power_on_do, sim.module(2).safe_do) == (1, 2))
        await wait_for(
            lambda: (
                sim.module(3).safe_ao == [100, 200, 300, 400]
                and sim.module(4).power_on_ao == [0x400]
            )
        )
        assert sim.module(1).do_bits == 0x8000  # the image's value is back after the latching
        assert sim.module(3).ao_raw == [0, 0, 0, 0]


async def test_animated_simulation_moves_the_gateway_inputs(gateway, wait_for):
    async with gateway([{"address": 1, "model": "I-7017"}], animate=True) as gw:
        await wait_for(lambda: gw.image["rs485/m1/ai0"].quality is Quality.GOOD)
        seen = {gw.read("rs485/m1/ai0")}
        await wait_for(lambda: seen.add(gw.read("rs485/m1/ai0")) or len(seen) >= 3)
