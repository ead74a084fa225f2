"""OpenCL device selection, program caching and `clrender info` (PoCL on the CPU)."""
import pytest

from clrender import cli, device


def test_default_device_is_available():
    rt = device.get_runtime()
    assert rt.name in [f"{d.platform.name.strip()} / {d.name.strip()}" for d in device.list_devices()]
    assert device.get_runtime() is rt  # cached per device


@pytest.mark.parametrize("spec", ["0", "0:0"])
def test_select_by_index(spec):
    assert device.select_device(spec) == device.list_devices()[0]


def test_select_by_name_substring():
    d = device.list_devices()[0]
    assert device.select_device(d.name.strip()[:6].upper()) == d


def test_no_match_lists_existing_devices():
    with pytest.raises(device.DeviceError) as exc:
        device.select_device("no-such-device-xyz")
    msg = str(exc.value)
    assert "no-such-device-xyz" in msg
    assert device.list_devices()[0].name.strip() in msg


def test_index_out_of_range_is_an_error():
    with pytest.raises(device.DeviceError, match="devices that exist"):
        device.select_device("99")


def test_env_variable_is_used(monkeypatch):
    monkeypatch.setenv("CLRENDER_DEVICE", "nothing-matches-this")
    with pytest.raises(device.DeviceError, match="nothing-matches-this"):
        device.select_device()


def test_program_built_once_per_options():
    rt = device.get_runtime()
    a = rt.program("camera.cl", {"UNUSED_DEFINE": 1})
    assert rt.program("camera.cl", {"UNUSED_DEFINE": 1}) is a
    assert rt.program("camera.cl", {"UNUSED_DEFINE": 2}) is not a
    assert a.kernel("generate_rays") is a.kernel("generate_rays")


def test_build_error_names_the_source():
    rt = device.get_runtime()
    with pytest.raises(RuntimeError, match="camera.cl"):
        rt.program("camera.cl", {"float": "syntax error here"})


def test_info_lists_the_device(capsys):
    assert cli.main(["info"]) == 0
    out = capsys.readouterr().out
    assert device.list_devices()[0].name.strip() in out
    assert "max_work_group_size" in out and "selected:" in out
