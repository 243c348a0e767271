"""What the wire fuzz campaign found, each as a test that failed before its fix."""

from __future__ import annotations

import pytest
from fuzz_targets import TARGETS, run_sync  # scripts/faults (see conftest)

from fieldgate.plugins.dcon.formats import DataFormat
from fieldgate.polling import CommError


def test_dcon_analog_reply_that_does_not_fit_the_learnt_format_rereads_the_format(tmp_path):
    """Without a checksum a line fault can turn the $AA2 reply into another valid-looking
    one: the back then reads hex data as engineering units and every read failed until the
    module had gone offline and its probe re-read $AA2. Now the read that does not fit
    makes the next poll read $AA2 first: one failed read, then good data again."""
    target = TARGETS["dcon"](tmp_path)
    module = next(m for m in target.modules if m.address == 2)  # I-7017, set to hex
    assert module.data_format is DataFormat.HEX
    target.valid_only = False
    target.wire = lambda valid: valid[:-3] + b"00\r" if valid.startswith(b"!02") else valid
    run_sync(module.read_config())  # a distorted reply: format 00 = engineering units
    assert module.data_format is DataFormat.ENGINEERING
    del target.wire  # the line is clean again
    target.valid_only = True
    with pytest.raises(CommError):
        run_sync(module.read_inputs())  # hex data do not parse as engineering units
    readings = run_sync(module.read_inputs())  # the next poll: $AA2 first, then the data
    assert module.data_format is DataFormat.HEX and len(readings) == len(module.inputs)
