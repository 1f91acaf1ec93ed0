"""The CPU model the records and reports name (``plant.machine.cpu_model``)."""

import platform

from plant import machine


def test_cpu_model_is_the_model_name_line_else_what_platform_reports(tmp_path, monkeypatch):
    info = tmp_path / "cpuinfo"
    info.write_text("processor\t: 0\nvendor_id\t: Acme\nmodel name\t: Acme X9 @ 3.0GHz\n"
                    "processor\t: 1\nmodel name\t: Acme X9 @ 3.0GHz\n")
    monkeypatch.setattr(machine, "Path", lambda _name: info)
    assert machine.cpu_model() == "Acme X9 @ 3.0GHz"
    info.unlink()  # no such file: the platform's name
    assert machine.cpu_model() == (platform.processor() or platform.machine() or "unknown")
