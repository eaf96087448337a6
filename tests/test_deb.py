"""The Debian package (deb/, `make deb`) installed by dpkg itself into a throwaway root:
`dpkg --root` with the maintainer scripts run outside a chroot (they act on $DPKG_ROOT), as
any user (--force-not-root). The package's dependencies are not installed there, so they
are waived (--force-depends).

The quick tests build the package with a venv that holds the wheel alone (the layout, the
scripts and the conffile are the real package's); the slow one builds it as `make deb`
does, with the daemon's dependencies, and runs the installed program."""

from __future__ import annotations

import os
import re
import shutil
import subprocess
from pathlib import Path

import pytest
from wheel_build import ROOT, build_deb

pytestmark = pytest.mark.skipif(shutil.which("dpkg-deb") is None or shutil.which("dpkg") is None,
                                reason="dpkg-deb and dpkg not available (make system-deps)")

VENV = "opt/furnace-daq/.venv"
CONFIG = "etc/furnace-daq/gateway.yaml"
UNIT = "lib/systemd/system/furnace-daq.service"
HEAVY = ("dask", "distributed", "pyarrow", "matplotlib")


def dpkg(root: Path, *args: str) -> subprocess.CompletedProcess:
    out = subprocess.run(["dpkg", f"--root={root}", "--log=/dev/null", "--force-not-root",
                          "--force-script-chrootless", "--force-depends", "--force-bad-path",
                          "--force-confold", *args],
                         capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stdout + out.stderr
    return out


def fake_root(path: Path) -> Path:
    """An empty root with an empty dpkg database."""
    admin = path / "var/lib/dpkg"
    for sub in ("info", "updates"):
        (admin / sub).mkdir(parents=True)
    for name in ("status", "available"):
        (admin / name).touch()
    return path


def installed_unit(root: Path, tmp_path: Path) -> Path:
    """The installed unit with its program's path inside the throwaway root, so that
    systemd-analyze checks the program the package installed."""
    text = (root / UNIT).read_text()
    program = "/opt/furnace-daq/.venv/bin/furnace-daq"
    assert f"ExecStart={program} run --config /etc/furnace-daq/gateway.yaml" in text
    path = tmp_path / "furnace-daq.service"
    path.write_text(text.replace(program, str(root / program.lstrip("/"))))
    return path


def verify(unit: Path) -> None:
    if shutil.which("systemd-analyze") is None:
        pytest.skip("systemd-analyze not available")
    out = subprocess.run(["systemd-analyze", "verify", "--man=no", "--recursive-errors=yes",
                          str(unit)], capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stdout + out.stderr


@pytest.fixture(scope="module")
def layout_deb(tmp_path_factory) -> Path:
    return build_deb.build(tmp_path_factory.mktemp("deb"), dependencies=False, fast=True)


def test_control_conffiles_and_contents(layout_deb, tmp_path):
    fields = subprocess.run(["dpkg-deb", "--field", str(layout_deb)], capture_output=True,
                            text=True, check=True).stdout
    assert re.search(r"^Package: furnace-daq$", fields, re.M)
    assert re.search(r"^Depends: python3\.11\b", fields, re.M)
    control = tmp_path / "control"
    subprocess.run(["dpkg-deb", "--control", str(layout_deb), str(control)], check=True)
    assert (control / "conffiles").read_text().split() == [f"/{CONFIG}"]
    for script in ("postinst", "prerm", "postrm"):
        assert (control / script).stat().st_mode & 0o111, script
    listing = subprocess.run(["dpkg-deb", "--contents", str(layout_deb)], capture_output=True,
                             text=True, check=True).stdout
    rows = [line.split() for line in listing.splitlines()]
    assert all(row[1] == "root/root" for row in rows)  # --root-owner-group, whoever built it
    paths = {row[5].removeprefix(".") for row in rows}
    for path in (f"/{VENV}/bin/furnace-daq", f"/{VENV}/bin/furnace-model", f"/{CONFIG}",
                 f"/{UNIT}", "/usr/lib/sysusers.d/furnace-daq.conf", "/usr/bin/furnace-daq",
                 "/usr/share/doc/furnace-daq/operations.md"):
        assert path in paths, path
    # logs and state are the service's (systemd creates them), not files of the package
    assert not any(p.startswith(("/var/log/", "/var/lib/")) for p in paths)


def test_install_reinstall_remove_purge(layout_deb, tmp_path):
    root = fake_root(tmp_path / "root")
    dpkg(root, "--install", str(layout_deb))
    venv = root / VENV
    script = (venv / "bin" / "furnace-daq").read_text()
    assert script.startswith("#!/opt/furnace-daq/.venv/bin/python\n"), script[:80]
    cfg = (venv / "pyvenv.cfg").read_text()
    assert "home = /usr/bin" in cfg and str(tmp_path) not in cfg
    assert os.readlink(root / "usr/bin/furnace-daq") == f"/{VENV}/bin/furnace-daq"
    assert not list(venv.glob("lib/python3*/site-packages/dask*"))
    # the venv's interpreter finds the package and its data inside the root
    out = subprocess.run([str(venv / "bin" / "python"), "-I", "-c",
                          "from furnace_model.shipped import shipped;"
                          "print(shipped('config/furnaces/six-zone.yaml'))"],
                         capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stderr
    assert Path(out.stdout.strip()).is_relative_to(venv) and Path(out.stdout.strip()).is_file()
    if shutil.which("systemd-sysusers"):
        passwd = (root / "etc/passwd").read_text()
        assert re.search(r"^furnace-daq:x:\d+:\d+:.*:/var/lib/furnace-daq:/usr/sbin/nologin$",
                         passwd, re.M), passwd
    verify(installed_unit(root, tmp_path))

    # a changed config survives an upgrade (here: the same package again)
    config = root / CONFIG
    config.write_text(config.read_text() + "# changed on site\n")
    dpkg(root, "--install", str(layout_deb))
    assert config.read_text().endswith("# changed on site\n")

    # what the service wrote while installed
    for path in ("var/log/furnace-daq/furnace-x.mcap", "var/lib/furnace-daq/model.json"):
        (root / path).parent.mkdir(parents=True, exist_ok=True)
        (root / path).write_text("x")
    dpkg(root, "--remove", "furnace-daq")
    assert not (venv / "bin" / "furnace-daq").exists() and not (root / UNIT).exists()
    assert config.is_file()  # remove keeps the config, the logs and the state
    assert (root / "var/log/furnace-daq/furnace-x.mcap").is_file()
    assert (root / "var/lib/furnace-daq/model.json").is_file()
    dpkg(root, "--purge", "furnace-daq")
    for gone in ("etc/furnace-daq", "var/log/furnace-daq", "var/lib/furnace-daq",
                 "opt/furnace-daq"):
        assert not (root / gone).exists(), gone


@pytest.mark.slow
def test_make_deb_installs_a_daemon_that_runs(tmp_path):
    deb = build_deb.build(tmp_path / "out")
    root = fake_root(tmp_path / "root")
    dpkg(root, "--install", str(deb))
    venv = root / VENV
    site = next(venv.glob("lib/python3*/site-packages"))
    assert (site / "numpy").is_dir() and (site / "foxglove").is_dir()
    assert not [m for m in HEAVY if (site / m).exists()]  # the daemon's dependencies only
    python = str(venv / "bin" / "python")
    for argv in (["--version"], ["config", "--furnace", "six-zone"]):
        out = subprocess.run([python, "-I", "-m", "furnace_daq.cli", *argv], capture_output=True,
                             text=True, timeout=120, cwd=tmp_path)
        assert out.returncode == 0, out.stderr
    assert "furnace: six-zone" in out.stdout
    check = subprocess.run([python, "-I", "-m", "furnace_daq.cli", "check", "--config",
                            str(root / CONFIG), "--plc", "127.0.0.1:1"],
                           capture_output=True, text=True, timeout=120)
    assert check.returncode == 1 and "Traceback" not in check.stderr, check.stderr
    verify(installed_unit(root, tmp_path))
    assert str(ROOT) not in (venv / "bin" / "furnace-daq").read_text()
