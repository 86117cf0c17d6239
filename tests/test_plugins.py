"""Plugin registries: entry points, in-process registration, helpful errors."""

from __future__ import annotations

import pytest

from followbot.services.runtime.plugins import Registry, UnknownPlugin


def test_installed_services_are_found_through_entry_points():
    reg = Registry("services")
    assert {"monitor", "synthetic"} <= set(reg.names())
    main = reg.load("synthetic")
    assert callable(main)


def test_unknown_name_lists_the_valid_ones():
    reg = Registry("services")
    with pytest.raises(UnknownPlugin, match=r"unknown service 'nope'; valid names: .*monitor"):
        reg.load("nope")


def test_registered_implementations_shadow_and_extend():
    reg = Registry("detectors")
    reg.register("mine", object)
    assert "mine" in reg.names()
    assert reg.load("mine") is object
    with pytest.raises(UnknownPlugin, match=r"unknown detector 'other'; valid names: .*mine"):
        reg.load("other")


def test_every_built_in_detector_is_an_installed_plugin():
    from followbot.services.laser_legs import DETECTORS

    reg = Registry("detectors")
    for name, (cls, settings_cls) in DETECTORS.items():
        loaded = reg.load(name)
        assert loaded is cls and loaded.name == name and loaded.settings_type is settings_cls
