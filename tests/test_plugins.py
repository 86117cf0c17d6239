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


def test_every_role_builds_its_plugins_settings_alike():
    """One way to turn a plugin's settings into its settings type, for all three roles: an
    unknown key names the role, the plugin and the key; None gives the defaults."""
    from followbot.services.laser_legs.detectors import make_detector
    from followbot.services.tracker.estimators import estimator_factory
    from followbot.services.vision_verify.verifiers import make_verifier

    for role, build in (
        ("detector 'thesis'", lambda s: make_detector("thesis", s)),
        ("estimator 'particle'", lambda s: estimator_factory("particle", s)),
        ("verifier 'histogram'", lambda s: make_verifier("histogram", s)),
    ):
        build(None)
        with pytest.raises(ValueError, match=rf"^{role}: .*no_such_key"):
            build({"no_such_key": 1})
