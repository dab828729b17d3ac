"""Build and install the `tf2_msgs` Python messages into this interpreter's environment.

    python tools/build_tf2_msgs.py [--force]

The PyPI `ros-jazzy-*` and `ros-kilted-*` wheels have rclpy, sensor_msgs and
geometry_msgs but no tf2_msgs, so the node could not subscribe /tf_static with
them. This generates the package from its message definition (tools/tf2_msgs:
TFMessage only) with the rosidl generator wheels of the environment's
distribution (`pip install -e '.[rosbuild]'` for Jazzy, `'.[rosbuild-kilted]'`
for Kilted), compiles it with CMake and a C/C++ compiler and installs it into
`sys.prefix`, next to the wheels. TFMessage and everything it nests are the same
in Humble, Jazzy and Kilted, so the type hash is the same in all three: the
build interoperates with a real install of either (tests/test_node_tf.py checks
the hash rclpy reports, under `make test` and `make test-kilted`).

Does nothing when tf2_msgs is already importable from elsewhere (a ROS
install) or when this definition was already built into this environment.
"""

from __future__ import annotations

import argparse
import hashlib
import importlib.util
import os
import shutil
import subprocess
import sys
import sysconfig
import tempfile
from pathlib import Path

SOURCE = Path(__file__).resolve().parent / 'tf2_msgs'
PREFIX = Path(sys.prefix)
STAMP = PREFIX / 'share' / 'tf2_msgs' / 'scanfuse-build-stamp'


def source_digest() -> str:
    digest = hashlib.sha256()
    for path in sorted(SOURCE.rglob('*')):
        if path.is_file():
            digest.update(path.relative_to(SOURCE).as_posix().encode())
            digest.update(path.read_bytes())
    digest.update(sys.version.encode())
    return digest.hexdigest()


def provided_elsewhere() -> Path | None:
    """Where tf2_msgs comes from when a ROS install (not this script) provides it."""
    spec = importlib.util.find_spec('tf2_msgs')
    if spec is None or spec.origin is None:
        return None
    origin = Path(spec.origin).resolve()
    return None if origin.is_relative_to(PREFIX.resolve()) else origin


def missing_tools() -> list[str]:
    needed = {'cmake': 'cmake (apt-get install cmake)', 'c++': 'a C/C++ compiler (apt install g++)'}
    missing = [text for tool, text in needed.items() if shutil.which(tool) is None]
    if (
        importlib.util.find_spec('rosidl_generator_py') is None
        or not (PREFIX / 'share' / 'rosidl_default_generators').is_dir()
    ):
        missing.append(
            "the rosidl generator wheels (pip install -e '.[rosbuild]' or '.[rosbuild-kilted]')"
        )
    return missing


def run(command: list[str], log: Path, env: dict[str, str]) -> None:
    with log.open('a', encoding='utf-8') as out:
        out.write(f'$ {" ".join(command)}\n')
        out.flush()
        result = subprocess.run(command, stdout=out, stderr=subprocess.STDOUT, env=env, check=False)  # noqa: S603
    if result.returncode != 0:
        tail = log.read_text(encoding='utf-8', errors='replace').splitlines()[-40:]
        print('\n'.join(tail), file=sys.stderr)
        msg = f'tf2_msgs: {command[0]} failed (exit {result.returncode}), its log ends above'
        raise SystemExit(msg)


def build(work: Path) -> None:
    env = {
        **os.environ,
        # ament's CMake helpers run `python3` scripts: they must be this environment's.
        'PATH': f'{PREFIX / "bin"}{os.pathsep}{os.environ.get("PATH", "")}',
        'AMENT_PREFIX_PATH': str(PREFIX),
        'CMAKE_PREFIX_PATH': str(PREFIX),
    }
    log = work / 'build.log'
    build_dir = work / 'build'
    run(
        [
            'cmake',
            '-S',
            str(SOURCE),
            '-B',
            str(build_dir),
            f'-DCMAKE_PREFIX_PATH={PREFIX}',
            f'-DCMAKE_INSTALL_PREFIX={PREFIX}',
            f'-DPython3_EXECUTABLE={sys.executable}',
            f'-DPython3_INCLUDE_DIR={sysconfig.get_paths()["include"]}',
            '-DBUILD_TESTING=OFF',
            '-DCMAKE_BUILD_TYPE=Release',
        ],
        log,
        env,
    )
    run(['cmake', '--build', str(build_dir), '--parallel', str(os.cpu_count() or 2)], log, env)
    run(['cmake', '--install', str(build_dir)], log, env)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--force', action='store_true', help='rebuild even when up to date')
    args = parser.parse_args()
    digest = source_digest()
    elsewhere = provided_elsewhere()
    if elsewhere is not None and not args.force:
        print(f'tf2_msgs: provided by {elsewhere}, nothing to build')
        return 0
    if STAMP.is_file() and STAMP.read_text(encoding='utf-8') == digest and not args.force:
        print(f'tf2_msgs: already built into {PREFIX}')
        return 0
    missing = missing_tools()
    if missing:
        print(f'tf2_msgs: cannot build, missing {", ".join(missing)}', file=sys.stderr)
        return 1
    with tempfile.TemporaryDirectory(prefix='tf2_msgs-') as tmp:
        print(f'tf2_msgs: building into {PREFIX} (about 20 s)')
        build(Path(tmp))
    check = subprocess.run(
        [sys.executable, '-c', 'from tf2_msgs.msg import TFMessage; TFMessage()'],
        capture_output=True,
        text=True,
        check=False,
    )
    if check.returncode != 0:
        print(check.stderr, file=sys.stderr)
        print('tf2_msgs: built, but `from tf2_msgs.msg import TFMessage` fails', file=sys.stderr)
        return 1
    STAMP.write_text(digest, encoding='utf-8')
    print('tf2_msgs: built and importable')
    return 0


if __name__ == '__main__':
    sys.exit(main())
