"""`make deb`: the gateway's Debian package, built with dpkg-deb from this tree.

The package holds a ready virtualenv, /opt/furnace-daq/.venv, built here from the wheel
and the daemon's dependencies with the PLC protocols' extras (`PLC_EXTRAS`: a gateway
talks to whatever PLC the plant has; the desk's fleet, report and Parquet extras are left
out), rather than a wheelhouse that postinst would
install from: installing then needs no network, no pip and no compiler on the gateway, takes
seconds, and dpkg knows every file it put there (`dpkg -L`, clean removal, `dpkg -V`). The
price is that the package is for one interpreter: Debian 12's /usr/bin/python3.11 on the
build's architecture, which `Depends:` says. The venv is built in a staging directory and
moved to its place: the paths written into it (script lines, pyvenv.cfg, compiled files)
are rewritten to /opt/furnace-daq/.venv.

Beside the venv: the commands linked into /usr/bin, the systemd unit in
/lib/systemd/system, the example config as the conffile /etc/furnace-daq/gateway.yaml, the
system user's sysusers.d entry, the docs, and the maintainer scripts of deb/ (user,
systemd, purge).

Building needs the network for pip (or PIP_FIND_LINKS/PIP_INDEX_URL pointing at a mirror);
run it on Debian 12 (make system-deps installs dpkg-dev and fakeroot).
"""

from __future__ import annotations

import argparse
import os
import re
import shutil
import subprocess
import sys
import tempfile
import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PLC_EXTRAS = ("opcua", "s7")
"""The extras of the PLC protocols beyond Modbus and CAN, installed into the package's venv."""
HERE = Path(__file__).resolve().parent
PREFIX = "/opt/furnace-daq"
VENV = f"{PREFIX}/.venv"
PYTHON = "/usr/bin/python3.11"
"""The interpreter the venv is made for: Debian 12's, which the package depends on."""
UNIT = "furnace-daq.service"
MAINTAINER = "Furnace DAQ maintainers <furnace-daq@localhost>"

WHEEL_SOURCES = ("pyproject.toml", "README.md", "furnace_model", "furnace_daq", "config",
                 "systemd")
"""What the wheel's build reads: the packages, and the directories their links lead to."""

MAINTAINER_SCRIPTS = ("postinst", "prerm", "postrm")


def version() -> str:
    return tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["version"]


def build_wheel(work: Path) -> Path:
    """The wheel of this tree, built from a copy of its sources: setuptools writes build/
    and *.egg-info beside what it builds, and two builds in the checkout would share them.
    No build isolation (the build's setuptools is the environment's), no network."""
    tree = work / "tree"
    tree.mkdir(parents=True)
    for name in WHEEL_SOURCES:
        source = ROOT / name
        if source.is_dir():
            shutil.copytree(source, tree / name, symlinks=True,
                            ignore=shutil.ignore_patterns("__pycache__"))
        else:
            shutil.copy2(source, tree / name)
    dist = work / "dist"
    _run([sys.executable, "-m", "pip", "wheel", "--quiet", "--no-deps",
          "--no-build-isolation", "--wheel-dir", str(dist), str(tree)])
    (wheel,) = dist.glob("furnace_daq-*.whl")
    return wheel


def stage(root: Path, wheel: Path, *, dependencies: bool = True,
          python: str = PYTHON) -> None:
    """Lay out the package's tree under `root` (DEBIAN/ included). Without `dependencies`
    the venv holds the wheel alone: the layout and the scripts are those of the real
    package, for a quick check; such a venv cannot run the daemon."""
    venv = root / VENV.lstrip("/")
    _run([python, "-m", "venv", "--without-pip", str(venv)])
    _run([sys.executable, "-m", "pip", "--python", str(venv / "bin" / "python"), "install",
          "--quiet", "--no-compile", "--no-warn-script-location",
          *([f"{wheel}[{','.join(PLC_EXTRAS)}]"] if dependencies else ["--no-deps", str(wheel)])])
    _relocate(venv)
    # Compiled here, by the gateway's interpreter, under the installed paths: the service's
    # /opt is read-only (ProtectSystem=strict), so nothing could be cached at run time.
    _run([python, "-m", "compileall", "-q", "-s", str(root), "-p", "/",
          "--invalidation-mode", "unchecked-hash", str(venv / "lib")])

    bin_dir = root / "usr/bin"
    bin_dir.mkdir(parents=True)
    for command in ("furnace-daq", "furnace-model"):
        (bin_dir / command).symlink_to(f"{VENV}/bin/{command}")
    _install(ROOT / "systemd" / UNIT, root / "lib/systemd/system" / UNIT)
    _install(ROOT / "config" / "gateway.yaml", root / "etc/furnace-daq/gateway.yaml")
    _install(HERE / "furnace-daq.sysusers", root / "usr/lib/sysusers.d/furnace-daq.conf")
    docs = root / "usr/share/doc/furnace-daq"
    _install(ROOT / "README.md", docs / "README.md")
    for doc in sorted((ROOT / "docs").glob("*.md")):
        _install(doc, docs / doc.name)

    debian = root / "DEBIAN"
    debian.mkdir()
    for name in MAINTAINER_SCRIPTS:
        _install(HERE / name, debian / name, mode=0o755)
    _install(HERE / "conffiles", debian / "conffiles")
    size_kib = sum(p.lstat().st_size for p in root.rglob("*")
                   if not p.is_dir() and debian not in p.parents) // 1024
    control = (HERE / "control").read_text()
    for key, value in (("VERSION", version()), ("ARCH", _architecture()),
                       ("MAINTAINER", MAINTAINER), ("INSTALLED_SIZE", str(size_kib))):
        control = control.replace(f"@{key}@", value)
    (debian / "control").write_text(control)


def _relocate(venv: Path) -> None:
    """Rewrite the staging path the venv was built at into its installed path."""
    staged = str(venv)
    texts = [venv / "pyvenv.cfg", *(p for p in (venv / "bin").iterdir()
                                    if p.is_file() and not p.is_symlink())]
    texts += list(venv.glob("lib/python*/site-packages/*.dist-info/direct_url.json"))
    for path in texts:
        data = path.read_bytes()
        if staged.encode() in data:
            path.write_bytes(data.replace(staged.encode(), VENV.encode()))


def _install(source: Path, target: Path, mode: int = 0o644) -> None:
    target.parent.mkdir(parents=True, exist_ok=True)
    shutil.copyfile(source, target)
    target.chmod(mode)


def _architecture() -> str:
    return _run(["dpkg", "--print-architecture"]).stdout.strip()


def build_deb(staged: Path, out_dir: Path, *, fast: bool = False) -> Path:
    """dpkg-deb's archive of a staged tree, owned by root whoever builds it. `fast`: gzip
    at its lowest level (for tests), else xz as Debian ships."""
    out_dir.mkdir(parents=True, exist_ok=True)
    control = (staged / "DEBIAN" / "control").read_text()
    fields = dict(re.findall(r"^(Package|Version|Architecture): (.+)$", control, re.M))
    deb = out_dir / f"{fields['Package']}_{fields['Version']}_{fields['Architecture']}.deb"
    compression = ["-Zgzip", "-z1"] if fast else ["-Zxz"]
    _run(["dpkg-deb", "--root-owner-group", *compression, "--build", str(staged), str(deb)])
    return deb


def build(out_dir: Path, *, dependencies: bool = True, fast: bool = False) -> Path:
    """Wheel, staged tree, .deb: the whole of `make deb`."""
    with tempfile.TemporaryDirectory(prefix="furnace-deb-") as tmp:
        work = Path(tmp)
        wheel = build_wheel(work / "wheel")
        staged = work / "root"
        stage(staged, wheel, dependencies=dependencies)
        return build_deb(staged, out_dir, fast=fast)


def _run(argv: list[str]) -> subprocess.CompletedProcess:
    out = subprocess.run(argv, capture_output=True, text=True,
                         env={**os.environ, "PIP_DISABLE_PIP_VERSION_CHECK": "1"})
    if out.returncode != 0:
        raise SystemExit(f"build_deb: {' '.join(argv[:4])} ... failed:\n{out.stderr.strip()}")
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", type=Path, default=Path("out/deb"), help="directory for the .deb")
    args = ap.parse_args(argv)
    for tool in ("dpkg-deb", "dpkg"):
        if shutil.which(tool) is None:
            print(f"build_deb: {tool} not found: make system-deps", file=sys.stderr)
            return 1
    if not Path(PYTHON).is_file():
        print(f"build_deb: {PYTHON} not found: the package is built on Debian 12",
              file=sys.stderr)
        return 1
    print(build(args.out))
    return 0


if __name__ == "__main__":
    sys.exit(main())
