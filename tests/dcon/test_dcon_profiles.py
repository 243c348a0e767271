"""Family profiles: model names, channel counts from the seeds, digital data layouts; topology validation."""

import pytest

from fieldgate import Kind, load_registry
from fieldgate.plugins.dcon.config import DconBackConfig
from fieldgate.plugins.dcon.profiles import PROFILES, find_profile
from fieldgate.polling import CommError
from fieldgate.topology import TopologyError, load_topology

# seed-003 §5.1 / seed-001 §2.1: model -> (DI, DO, AI, AO)
SEED_CHANNELS = {
    "I-7011": (1, 2, 1, 0),
    "I-7012": (1, 2, 1, 0),
    "I-7013": (0, 0, 1, 0),
    "I-7014": (1, 2, 1, 0),
    "I-7015": (0, 0, 6, 0),
    "I-7016": (1, 4, 2, 0),
    "I-7016P": (1, 4, 1, 0),
    "I-7017": (0, 0, 8, 0),
    "I-7018": (0, 0, 8, 0),
    "I-7019R": (0, 0, 8, 0),
    "I-7021": (0, 0, 0, 1),
    "I-7022": (0, 0, 0, 2),
    "I-7024": (0, 0, 0, 4),
    "I-7033": (0, 0, 3, 0),
    "I-7041": (14, 0, 0, 0),
    "I-7042": (0, 13, 0, 0),
    "I-7043": (0, 16, 0, 0),
    "I-7044": (4, 8, 0, 0),
    "I-7045": (0, 16, 0, 0),
    "I-7050": (7, 8, 0, 0),
    "I-7051": (16, 0, 0, 0),
    "I-7052": (8, 0, 0, 0),
    "I-7053": (16, 0, 0, 0),
    "I-7055": (8, 8, 0, 0),
    "I-7058": (8, 0, 0, 0),
    "I-7060": (4, 4, 0, 0),
    "I-7063": (8, 3, 0, 0),
    "I-7065": (4, 5, 0, 0),
    "I-7066": (0, 7, 0, 0),
    "I-7067": (0, 7, 0, 0),
    "I-87013": (0, 0, 4, 0),
    "I-87016": (0, 0, 2, 0),
    "I-87017": (0, 0, 8, 0),
    "I-87018": (0, 0, 8, 0),
    "I-87019R": (0, 0, 8, 0),
    "I-87022": (0, 0, 0, 2),
    "I-87024": (0, 0, 0, 4),
    "I-87026": (0, 0, 0, 2),
    "I-87040": (32, 0, 0, 0),
    "I-87041": (0, 32, 0, 0),
    "I-87051": (16, 0, 0, 0),
    "I-87052": (8, 0, 0, 0),
    "I-87053": (16, 0, 0, 0),
    "I-87054": (8, 8, 0, 0),
    "I-87055": (8, 8, 0, 0),
    "I-87057": (0, 16, 0, 0),
    "I-87058": (8, 0, 0, 0),
    "I-87063": (4, 4, 0, 0),
    "I-87064": (0, 8, 0, 0),
    "I-87065": (0, 8, 0, 0),
    "I-87066": (0, 8, 0, 0),
    "I-87068": (0, 8, 0, 0),
    "I-87069": (0, 8, 0, 0),
}


@pytest.mark.parametrize("model, counts", sorted(SEED_CHANNELS.items()))
def test_channel_counts_follow_the_seeds(model, counts):
    p = find_profile(model)
    assert p is not None, model
    assert (p.di, p.do, p.ai, p.ao) == counts


@pytest.mark.parametrize(
    "name, model",
    [
        ("7017", "I-7017"),
        ("7017RC", "I-7017"),
        ("I-7053D", "I-7053"),
        ("M-7055D", "I-7055"),
        ("7012FD", "I-7012"),
        ("87017R", "I-87017"),
        ("I-7018BL", "I-7018"),
        ("m-7017r-a5", "I-7017"),
        ("7016P", "I-7016P"),
        ("7063BD", "I-7063"),
    ],
)
def test_model_names_as_modules_report_them(name, model):
    assert find_profile(name).model == model


@pytest.mark.parametrize("name", ["7099", "", "I-", "87999", "ABC"])
def test_unknown_models(name):
    assert find_profile(name) is None


def test_digital_layouts():
    p = find_profile("I-7060")  # 4 DI, 4 DO: outputs then inputs
    assert p.encode_dio(0x0A, 0x05) == "0A05" and p.decode_dio("0A05") == (0x0A, 0x05)
    p = find_profile("I-7053")  # 16 DI: one 16-bit value, bit n = DI n
    assert p.decode_dio("8001") == (0, 0x8001)
    p = find_profile("I-7052")  # 8 DI: byte then 00
    assert p.encode_dio(0, 0xA5) == "A500"
    p = find_profile("I-7043")  # 16 DO
    assert p.decode_dio("1234") == (0x1234, 0) and p.encode_do(0x1234) == "1234"
    p = find_profile("I-7041")  # 14 DI: bits above 13 masked
    assert p.decode_dio("FFFF") == (0, 0x3FFF)
    p = find_profile("I-87040")
    assert p.decode_dio("80000001") == (0, 0x80000001)
    assert find_profile("I-7060").encode_do(0xF) == "F"  # one character for up to 4 outputs
    assert find_profile("I-7042").encode_do(0x1FFF) == "1FFF"
    with pytest.raises(CommError):
        find_profile("I-7060").decode_dio("0A0")
    with pytest.raises(CommError):
        find_profile("I-7060").decode_dio("0AZ5")


def test_every_profile_round_trips_its_digital_data():
    for p in PROFILES:
        if p.digital != "dio":
            continue
        do_bits, di_bits = (1 << p.do) - 1, (1 << p.di) - 1
        assert p.decode_dio(p.encode_dio(do_bits, di_bits)) == (do_bits, di_bits), p.model


def _back(**module):
    return {
        "name": "rs485",
        "type": "dcon",
        "port": "/dev/null",
        "modules": [{"address": 1, "model": "I-7017", **module}],
    }


def _topology(back):
    return {
        "gateway": {"name": "g"},
        "fronts": [{"name": "plc", "type": "memory"}],
        "backs": [back],
    }


@pytest.fixture(scope="module")
def registry():
    return load_registry()


@pytest.mark.parametrize(
    "back, message",
    [
        (_back(model="I-7099"), "unknown DCON module 'I-7099'"),
        (_back(type_code=0x30), "type code 0x30 is not one of I-7017's"),
        (_back(model="I-7053", type_code=0x08), "digital module"),
        (_back(model="I-7043", safe_value=0x1FFFF), "bit pattern of its 16 outputs"),
        (_back(model="I-7024", safe_value=[1, 2]), "needs 4 values"),
        (_back(safe_value=1), "has no outputs"),
        (_back(data_format="octal"), "data_format"),
        (_back(watchdog={"timeout_ms": 50}), "timeout_ms"),
        ({**_back(watchdog={"timeout_ms": 1000}), "host_ok_ms": 600}, "less than half"),
        (
            {
                **_back(),
                "modules": [{"address": 1, "model": "I-7017"}, {"address": 1, "model": "I-7053"}],
            },
            "two modules at address 1",
        ),
        (_back(address=256), "address"),
    ],
)
def test_topology_errors(registry, back, message):
    with pytest.raises(TopologyError) as exc:
        load_topology(_topology(back), registry)
    assert message in str(exc.value) or any(message in str(i) for i in exc.value.issues)


def test_channel_specs_follow_the_model(registry):
    back = {
        "name": "rs485",
        "type": "dcon",
        "port": "/dev/null",
        "modules": [
            {"address": 4, "model": "I-7012", "type_code": 0x08, "error_mode": {"value": 1}},
            {"address": 1, "model": "I-87026"},
        ],
    }
    topo = load_topology(_topology(back), registry)
    specs = {s.id: s for s in topo.channel_specs}
    assert sorted(specs) == [
        "rs485/m1/ao0",
        "rs485/m1/ao1",
        "rs485/m4/ai0",
        "rs485/m4/di0",
        "rs485/m4/do0",
        "rs485/m4/do1",
    ]
    assert (
        specs["rs485/m4/do1"].error_mode.use_value and specs["rs485/m4/do1"].error_mode.value == 1
    )
    assert specs["rs485/m4/ai0"].scaling.eng_max == 10.0 and specs["rs485/m4/ai0"].kind is Kind.AI
    assert specs["rs485/m1/ao0"].data_type.value == "uint16"  # I-87026: 0..0xFFFF
    assert DconBackConfig.model_validate({**back, "host_ok_ms": None}).host_ok_period() is None
