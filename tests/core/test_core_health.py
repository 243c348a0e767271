"""Module health: counters wrap at 16 bits, offline after more than N failures, recovery."""

from fieldgate import ErrorKind, HealthEvent, HealthRegistry, ModuleHealth


def test_error_counter_wraps_at_16_bits_and_clears():
    h = ModuleHealth("rs485", 1)
    h.error_counter = 0xFFFE
    h.record_failure(ErrorKind.TIMEOUT, "t")
    assert h.error_counter == 0xFFFF
    h.record_failure(ErrorKind.CRC, "c")
    assert h.error_counter == 0
    h.record_failure(ErrorKind.CRC, "c")
    h.clear_error_counter()
    assert h.error_counter == 0
    assert h.errors[ErrorKind.CRC] == 2 and h.errors[ErrorKind.TIMEOUT] == 1


def test_offline_on_the_failure_after_the_threshold_then_online_on_success():
    events = []
    registry = HealthRegistry()
    h = registry.add(ModuleHealth("rs485", 5, fail_threshold=3))
    registry.subscribe(lambda m, e: events.append((m.address, e)))
    results = [h.record_failure(ErrorKind.TIMEOUT, "no answer") for _ in range(5)]
    assert results == [False, False, False, True, False]  # "more than three times"
    assert not h.online and h.consecutive_failures == 5 and h.last_error == "no answer"
    assert events.count((5, HealthEvent.OFFLINE)) == 1
    assert h.record_success(0.002, 1.0) is True
    assert h.online and h.consecutive_failures == 0 and h.error_counter == 5
    assert (5, HealthEvent.ONLINE) in events
    assert h.record_success(0.002, 2.0) is False


def test_success_resets_the_consecutive_count():
    h = ModuleHealth("rs485", 2, fail_threshold=3)
    for _ in range(3):
        h.record_failure(ErrorKind.TIMEOUT, "x")
    h.record_success()
    for _ in range(3):
        assert h.record_failure(ErrorKind.TIMEOUT, "x") is False
    assert h.online


def test_registry_rejects_duplicates_and_filters_by_back():
    registry = HealthRegistry()
    registry.add(ModuleHealth("a", 1))
    registry.add(ModuleHealth("b", 1))
    try:
        registry.add(ModuleHealth("a", 1))
    except ValueError as exc:
        assert "declared twice" in str(exc)
    else:
        raise AssertionError("duplicate module accepted")
    assert [m.back for m in registry.modules("b")] == ["b"]
    assert registry.get("a", 1).as_dict()["online"] is True
