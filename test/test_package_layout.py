"""What `colcon build` + `ros2 run usv_predictor ...` rely on, checked on a real build.

The repository (tracked and untracked-but-not-ignored files) is copied to a temporary workspace
and built there with the virtualenv's colcon, so build/, install/ and log/ never land in the tree.
Also checks the CI guard of conftest.raw_data_dir in a throw-away pytest run.
"""
from __future__ import annotations

import ast
import os
import re
import shutil
import stat
import subprocess
import sys
import xml.etree.ElementTree as ElementTree
from pathlib import Path

import pytest
from replay_helpers import pinned_tool

import usv_predictor

REPO_ROOT = Path(__file__).resolve().parents[1]
PACKAGE = "usv_predictor"
BUILD_TIMEOUT_S = 120
IGNORED_WITHOUT_GIT = shutil.ignore_patterns(".git", ".venv", "build", "install", "log", "out", "__pycache__",
                                             "*.egg-info", ".pytest_cache")


def colcon_executable() -> str:
    return pinned_tool("colcon")


def repo_files() -> list[str]:
    """Tracked and untracked-but-not-ignored files: what a commit of the tree would build."""
    listed = subprocess.run(
        ["git", "ls-files", "--cached", "--others", "--exclude-standard", "-z"],
        cwd=REPO_ROOT, capture_output=True, check=True, timeout=30,
    )
    return [name for name in listed.stdout.decode().split("\0") if name and (REPO_ROOT / name).is_file()]


def copy_repo(destination: Path) -> None:
    try:
        names = repo_files()
    except (OSError, subprocess.CalledProcessError):
        shutil.copytree(REPO_ROOT, destination, ignore=IGNORED_WITHOUT_GIT)  # not a git checkout
        return
    for name in names:
        target = destination / name
        target.parent.mkdir(parents=True, exist_ok=True)
        shutil.copy2(REPO_ROOT / name, target)


def clean_env() -> dict[str, str]:
    """The environment without any sourced ROS workspace, so only our install can answer."""
    return {k: v for k, v in os.environ.items() if k not in ("AMENT_PREFIX_PATH", "COLCON_PREFIX_PATH",
                                                           "CMAKE_PREFIX_PATH", "PYTHONPATH")}


@pytest.fixture(scope="module")
def installed(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Build the package with colcon in a temporary workspace; return its install prefix."""
    workspace = tmp_path_factory.mktemp("colcon_ws")
    artefacts_before = {name: (REPO_ROOT / name).exists() for name in ("build", "install", "log")}
    copy_repo(workspace / "src" / PACKAGE)
    command = [
        colcon_executable(), "--log-base", str(workspace / "log"), "build",
        "--base-paths", str(workspace / "src"),
        "--build-base", str(workspace / "build"),
        "--install-base", str(workspace / "install"),
    ]
    done = subprocess.run(command, cwd=workspace, capture_output=True, text=True, timeout=BUILD_TIMEOUT_S,
                          env=clean_env())
    assert done.returncode == 0, f"colcon build failed:\n{done.stdout[-4000:]}\n{done.stderr[-4000:]}"
    assert {name: (REPO_ROOT / name).exists() for name in artefacts_before} == artefacts_before  # tree untouched
    return workspace / "install" / PACKAGE


def installed_env(prefix: Path) -> dict[str, str]:
    """What `source install/setup.bash` provides for a Python package: the ament index and PYTHONPATH."""
    site = prefix / "lib" / f"python{sys.version_info.major}.{sys.version_info.minor}" / "site-packages"
    return {**clean_env(), "AMENT_PREFIX_PATH": str(prefix), "PYTHONPATH": str(site),
            "ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST"}


def test_ament_index_marker_is_installed(installed: Path) -> None:
    assert (installed / "share" / "ament_index" / "resource_index" / "packages" / PACKAGE).is_file()


def test_ament_index_python_finds_the_prefix(installed: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    from ament_index_python.packages import get_package_prefix, get_package_share_directory

    monkeypatch.setenv("AMENT_PREFIX_PATH", str(installed))
    assert Path(get_package_prefix(PACKAGE)) == installed
    assert Path(get_package_share_directory(PACKAGE)) == installed / "share" / PACKAGE


@pytest.mark.parametrize("executable", ["predictor", "replay"])
def test_executables_are_where_ros2_run_looks_and_answer_help(installed: Path, executable: str) -> None:
    path = installed / "lib" / PACKAGE / executable
    assert path.is_file(), f"{path} missing: ros2 run {PACKAGE} {executable} would not find it"
    assert path.stat().st_mode & stat.S_IXUSR
    done = subprocess.run([str(path), "--help"], capture_output=True, text=True, timeout=60,
                          env=installed_env(installed))
    assert done.returncode == 0, done.stderr
    assert done.stdout.lstrip().startswith("usage:")


def test_share_files_are_installed(installed: Path) -> None:
    share = installed / "share" / PACKAGE
    assert (share / "package.xml").read_bytes() == (REPO_ROOT / "package.xml").read_bytes()
    assert (share / "config" / "predictor.yaml").read_bytes() == (REPO_ROOT / "config" / "predictor.yaml").read_bytes()
    presets = {p.name for p in (REPO_ROOT / "config" / "vessels").glob("*.yaml")}
    assert {p.name for p in (share / "config" / "vessels").glob("*.yaml")} == presets
    for folder in ("bags", "models"):
        shipped = {p.relative_to(REPO_ROOT) for p in (REPO_ROOT / folder).rglob("*") if p.is_file()
                   and "__pycache__" not in p.parts} if (REPO_ROOT / folder).is_dir() else set()
        tracked = shipped & {Path(name) for name in repo_files()}
        got = {p.relative_to(share) for p in (share / folder).rglob("*") if p.is_file()} if shipped else set()
        assert tracked <= got, f"{folder}/ files not installed: {sorted(map(str, tracked - got))}"


def test_installed_code_reads_installed_config(installed: Path) -> None:
    """Run from the install (no source tree beside it), the loader finds its data via the ament index."""
    probe = ("import usv_predictor, usv_predictor.config as c; "
             "print(usv_predictor.__file__); print(c.default_config_path()); print(c.load_predictor_config().vessel)")
    done = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, timeout=60,
                          env=installed_env(installed), cwd=installed)
    assert done.returncode == 0, done.stderr
    module_file, config_path, vessel = done.stdout.split()
    assert Path(module_file).is_relative_to(installed)
    assert Path(config_path) == installed / "share" / PACKAGE / "config" / "predictor.yaml"
    assert vessel


def test_versions_agree() -> None:
    """package.xml, usv_predictor.__version__ and setup.py (which reads __version__) are one number."""
    root = ElementTree.parse(REPO_ROOT / "package.xml").getroot()
    assert root.get("format") == "3"
    assert root.findtext("name") == PACKAGE
    assert root.findtext("version") == usv_predictor.__version__
    assert root.find("export/build_type").text == "ament_python"
    setup_text = (REPO_ROOT / "setup.py").read_text(encoding="utf-8")
    assert re.search(r"version=read_version\(\)", setup_text)


def test_setup_cfg_puts_scripts_where_ros2_run_looks() -> None:
    text = (REPO_ROOT / "setup.cfg").read_text(encoding="utf-8")
    assert f"script_dir=$base/lib/{PACKAGE}" in text
    assert f"install_scripts=$base/lib/{PACKAGE}" in text


# ----------------------------------------------------------------------------- declared dependencies

# Every third-party import of the installed packages -> how a colcon user gets it. "rosdep": an exec_depend key of
# package.xml (ROS packages of ros/rosdistro's jazzy distribution; python3-* keys of its rosdep/python.yaml, where
# python3-numpy, python3-yaml, python3-matplotlib and python3-pytest resolve on Debian and Ubuntu). "pip": no usable
# rosdep key, installed by the README's pip line with the pin of requirements.txt (python.yaml has no torch key but
# the end-of-life alias python3-pytorch-pip, no rosbags or openpyxl key, and python3-numba for Ubuntu bionic and
# focal only). "stdlib": in the standard library of a newer Python than 3.11.
IMPORT_DEPENDENCIES: dict[str, tuple[str, str]] = {
    "numpy": ("rosdep", "python3-numpy"),
    "yaml": ("rosdep", "python3-yaml"),
    "matplotlib": ("rosdep", "python3-matplotlib"),
    "rclpy": ("rosdep", "rclpy"),
    "rcl_interfaces": ("rosdep", "rcl_interfaces"),
    "ament_index_python": ("rosdep", "ament_index_python"),
    "diagnostic_msgs": ("rosdep", "diagnostic_msgs"),
    "torch": ("pip", "torch"),
    "rosbags": ("pip", "rosbags"),
    "backports": ("pip", "rosbags"),  # backports.zstd, rosbags' own dependency before Python 3.14
    "openpyxl": ("pip", "openpyxl"),
    "numba": ("pip", "numba"),
    "llvmlite": ("pip", "llvmlite"),  # numba's own, imported by the kernel for the sqrt instruction (physics/kernel.py)
    "compression": ("stdlib", "Python 3.14"),
}
# Message packages named in type strings ("sensor_msgs/msg/Imu") of the code and of config/predictor.yaml.
MESSAGE_PACKAGE = re.compile(r"\b([a-z][a-z0-9_]*(?:_msgs|_interfaces))/(?:msg/)?[A-Z]")
OWN_PACKAGES = {PACKAGE, "msg_adapters"}


def package_xml_depends(tag: str) -> set[str]:
    root = ElementTree.parse(REPO_ROOT / "package.xml").getroot()
    return {element.text.strip() for element in root.findall(tag)}


def runtime_imports() -> dict[str, set[str]]:
    """Top-level names imported anywhere in the installed packages (function-local imports too) -> the files."""
    found: dict[str, set[str]] = {}
    for folder in OWN_PACKAGES:
        for path in sorted((REPO_ROOT / folder).rglob("*.py")):
            tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
            for node in ast.walk(tree):
                if isinstance(node, ast.Import):
                    names = [alias.name for alias in node.names]
                elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                    names = [node.module]
                else:
                    continue
                for name in names:
                    top = name.split(".")[0]
                    if top not in sys.stdlib_module_names and top not in OWN_PACKAGES and top != "__future__":
                        found.setdefault(top, set()).add(str(path.relative_to(REPO_ROOT)))
    return found


def message_packages() -> set[str]:
    texts = [(REPO_ROOT / "config" / "predictor.yaml").read_text(encoding="utf-8")]
    for folder in OWN_PACKAGES:
        texts += [path.read_text(encoding="utf-8") for path in (REPO_ROOT / folder).rglob("*.py")]
    return {match.group(1) for text in texts for match in MESSAGE_PACKAGE.finditer(text)}


def requirement_pins() -> dict[str, str]:
    pins = {}
    for line in (REPO_ROOT / "requirements.txt").read_text(encoding="utf-8").splitlines():
        match = re.match(r"^([A-Za-z0-9_.-]+)==(\S+)", line.strip())
        if match:
            pins[match.group(1).lower()] = match.group(2)
    return pins


def readme_pip_pins() -> dict[str, str]:
    """name -> version of the README's pip line(s) for the colcon path."""
    lines = [line for line in (REPO_ROOT / "README.md").read_text(encoding="utf-8").splitlines()
             if line.startswith("python3 -m pip install")]
    assert lines, "README.md has no `python3 -m pip install` line for what rosdep cannot install"
    pairs = [pair for line in lines for pair in re.findall(r"([A-Za-z0-9_.-]+)==(\S+)", line)]
    return {name.lower(): version for name, version in pairs}


def test_every_runtime_import_has_a_declared_source() -> None:
    imports = runtime_imports()
    unknown = {name: sorted(files) for name, files in imports.items() if name not in IMPORT_DEPENDENCIES}
    assert not unknown, ("imports with no entry in IMPORT_DEPENDENCIES (declare each in package.xml or the pip line): "
                         f"{unknown}")
    declared = package_xml_depends("exec_depend")
    for name in imports:
        kind, key = IMPORT_DEPENDENCIES[name]
        if kind == "rosdep":
            assert key in declared, (f"{name} (imported by {sorted(imports[name])}) needs "
                                     f"<exec_depend>{key}</exec_depend>")


def test_every_message_package_is_declared() -> None:
    missing = message_packages() - package_xml_depends("exec_depend")
    assert not missing, f"message packages used but not in package.xml: {sorted(missing)}"


def test_what_rosdep_cannot_install_has_the_readme_pip_line_with_the_pins() -> None:
    pins, readme = requirement_pins(), readme_pip_pins()
    for kind, name in sorted(set(IMPORT_DEPENDENCIES.values())):
        if kind != "pip":
            continue
        assert name in readme, f"{name}: not in the README's pip line"
        if name in pins:
            assert readme[name] == pins[name], f"{name}: README pins {readme[name]}, requirements.txt {pins[name]}"
    assert "--index-url https://download.pytorch.org/whl/cpu torch==" in (REPO_ROOT / "README.md").read_text(
        encoding="utf-8"), "torch must come from the CPU index (the default index pulls the CUDA build)"


def test_package_xml_declares_only_known_keys() -> None:
    """No exec_depend that no import or message type asks for (a key rosdep lacks would stop `rosdep install`)."""
    wanted = {key for kind, key in IMPORT_DEPENDENCIES.values() if kind == "rosdep"} | message_packages()
    assert package_xml_depends("exec_depend") <= wanted


def test_installed_modules_import_from_the_install(installed: Path) -> None:
    """Every module of the install (but the __main__ entry points, which run) imports with what the environment
    provides: a missing runtime dependency fails here, where `--help` alone would not reach the import."""
    probe = ("import importlib, pkgutil, sys; import usv_predictor, msg_adapters\n"
             "names = [m.name for p in (usv_predictor, msg_adapters)\n"
             "         for m in pkgutil.walk_packages(p.__path__, p.__name__ + '.')\n"
             "         if not m.name.endswith('.__main__')]\n"
             "for name in names: importlib.import_module(name)\n"
             "print(len(names)); print(usv_predictor.__file__); print(msg_adapters.__file__)")
    done = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, timeout=60,
                          env=installed_env(installed), cwd=installed)
    assert done.returncode == 0, done.stderr[-4000:]
    count, *files = done.stdout.split()
    assert int(count) > 50
    assert all(Path(file).is_relative_to(installed) for file in files)


# ----------------------------------------------------------------------------- the CI guard


def run_raw_data_probe(tmp_path: Path, ci: str | None) -> subprocess.CompletedProcess[str]:
    """Run a one-test pytest session whose repo has no ../shared/data/raw, with CI set or not."""
    repo = tmp_path / "repo"
    (repo / "test").mkdir(parents=True)
    shutil.copy2(REPO_ROOT / "test" / "conftest.py", repo / "test" / "conftest.py")
    (repo / "test" / "test_probe.py").write_text(
        "def test_uses_raw(raw_data_dir):\n    assert raw_data_dir.is_dir()\n", encoding="utf-8"
    )
    env = {k: v for k, v in os.environ.items() if k != "CI"}
    if ci is not None:
        env["CI"] = ci
    return subprocess.run([sys.executable, "-m", "pytest", "-q", "-rs", "-p", "no:cacheprovider", "test"],
                          cwd=repo, capture_output=True, text=True, timeout=60, env=env)


def test_raw_data_skip_outside_ci_and_failure_under_ci(tmp_path: Path) -> None:
    outside = run_raw_data_probe(tmp_path / "a", ci=None)
    assert outside.returncode == 0, outside.stdout
    assert "1 skipped" in outside.stdout, outside.stdout
    assert "shared/data/raw is absent" in outside.stdout
    under_ci = run_raw_data_probe(tmp_path / "b", ci="true")
    assert under_ci.returncode == 1, under_ci.stdout
    assert "1 error" in under_ci.stdout, under_ci.stdout
    assert "CI is set, so tests on real data must not be skipped" in under_ci.stdout
    (tmp_path / "c" / "shared" / "data" / "raw").mkdir(parents=True)
    (tmp_path / "c" / "shared" / "data" / "raw" / "some_set").mkdir()
    present = run_raw_data_probe(tmp_path / "c", ci="true")
    assert present.returncode == 0, present.stdout
    assert "1 passed" in present.stdout, present.stdout


def test_raw_data_dir_fixture_here(raw_data_dir: Path) -> None:
    """In this checkout the fixture yields the shared raw data folder (CI must have it)."""
    assert raw_data_dir == REPO_ROOT.parent / "shared" / "data" / "raw"
    assert any(raw_data_dir.iterdir())
