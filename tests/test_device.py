"""OpenCL device selection and ranking, the exact build's precondition, program caching
and `clrender info` (PoCL on the CPU; Intel's CPU runtime where pip installed it)."""
from dataclasses import dataclass

import pyopencl as cl
import pytest

from clrender import cli, device, icd
from deps import require


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


@dataclass(frozen=True)
class _Platform:
    name: str


@dataclass(frozen=True)
class _Device:
    """What rank / choice_reason / exact_options read of a cl.Device."""
    name: str
    type: int
    max_compute_units: int
    platform: _Platform = _Platform("Some Platform")
    host_unified_memory: bool = False
    single_fp_config: int = 0


GPU, CPU = int(cl.device_type.GPU), int(cl.device_type.CPU)


def test_rank_discrete_gpu_then_integrated_then_cpu_then_compute_units(monkeypatch):
    monkeypatch.setattr(device, "_compiles", lambda d: True)
    cpu_small, cpu_big = _Device("cpu2", CPU, 2), _Device("cpu8", CPU, 8)
    igpu = _Device("igpu", GPU, 96, host_unified_memory=True)
    dgpu_small, dgpu_big = _Device("dgpu20", GPU, 20), _Device("dgpu80", GPU, 80)
    ranked = device.rank([cpu_small, igpu, cpu_big, dgpu_small, dgpu_big])
    assert [d.name for d in ranked] == ["dgpu80", "dgpu20", "igpu", "cpu8", "cpu2"]
    assert "more compute units (80 against 20)" in device.choice_reason(dgpu_big, ranked)
    assert "discrete GPU before integrated GPU" in device.choice_reason(dgpu_small,
                                                                        [dgpu_small, igpu])
    assert "integrated GPU before CPU" in device.choice_reason(igpu, [cpu_big, igpu])


def test_rank_puts_a_pip_runtime_after_the_system_driver_on_a_tie(monkeypatch):
    monkeypatch.setattr(device, "_compiles", lambda d: True)
    pip_rt = _Device("intel", CPU, 2, _Platform("Intel(R) OpenCL"))
    system = _Device("pocl", CPU, 2, _Platform("Portable Computing Language"))
    monkeypatch.setattr(icd, "from_pip", lambda name: "intel-opencl-rt"
                        if name == "Intel(R) OpenCL" else None)
    assert device.rank([pip_rt, system]) == [system, pip_rt]
    assert "system's driver before intel-opencl-rt from pip" in device.choice_reason(
        system, [pip_rt, system])
    # More compute units still win over where the driver came from.
    big_pip = _Device("intel", CPU, 4, _Platform("Intel(R) OpenCL"))
    assert device.rank([system, big_pip]) == [big_pip, system]


def test_exact_build_option_only_where_reported(monkeypatch):
    reported = _Device("a", CPU, 2, single_fp_config=int(
        cl.device_fp_config.CORRECTLY_ROUNDED_DIVIDE_SQRT | cl.device_fp_config.INF_NAN))
    assert device.exact_options(reported) == (device.CORRECTLY_ROUNDED,)
    silent = _Device("b", CPU, 2, single_fp_config=int(cl.device_fp_config.INF_NAN))
    monkeypatch.setattr(device, "_divide_sqrt_mismatches", lambda d: 0)
    assert device.exact_options(silent) == ()
    monkeypatch.setattr(device, "_divide_sqrt_mismatches", lambda d: 7)
    with pytest.raises(device.DeviceError, match="cannot match the numpy references"):
        device.exact_options(silent)


@pytest.mark.parametrize("d", device.list_devices(), ids=lambda d: d.platform.name.strip())
def test_exact_build_of_every_device_here_follows_its_report_or_the_probe(d):
    if not device._compiles(d):
        pytest.skip(f"{d.name.strip()} builds no kernel")
    if d.single_fp_config & cl.device_fp_config.CORRECTLY_ROUNDED_DIVIDE_SQRT:
        assert device.exact_options(d) == (device.CORRECTLY_ROUNDED,)
    elif device._divide_sqrt_mismatches(d) == 0:   # Intel's CPU runtime
        assert device.exact_options(d) == ()
    else:
        with pytest.raises(device.DeviceError, match="cannot match"):
            device.exact_options(d)


def test_platform_name_or_version_before_device_name():
    devices = device.list_devices()
    intel = [d for d in devices if d.platform.name.strip() == "Intel(R) OpenCL"]
    pocl = [d for d in devices if "pocl" in d.platform.version.lower()]
    require(bool(pocl), "PoCL (apt install pocl-opencl-icd)")
    assert device.select_device("pocl") == pocl[0]
    if intel:  # PoCL's device names say "Intel(R) Xeon" too: the platform's name wins
        assert device.select_device("intel") == intel[0]


def test_info_names_every_platform_and_why_it_chose(capsys, monkeypatch):
    monkeypatch.delenv("CLRENDER_DEVICE", raising=False)
    assert cli.main(["info"]) == 0
    out = capsys.readouterr().out
    for d in device.list_devices():
        assert d.platform.name.strip() in out
    chosen = device.select_device()
    assert f"selected: {chosen.platform.name.strip()} / {chosen.name.strip()} " \
           f"({device.choice_reason(chosen)})" in out
    assert out.count("exact_build") == len(device.list_devices())
