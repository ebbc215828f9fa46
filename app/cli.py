"""The `photoar` command line.

  photoar composite SCENE_DIR --out DIR [--passes N] [--mode ldr|hdr] ...
  photoar demo [--out DIR]

Bad input ends with one line `photoar: error: <file>: <problem>` and exit status 2, and
nothing is written to --out; a bad option gives one line `photoar <subcommand>: error: <problem>
(photoar <subcommand> --help)`, exit status 2 (PhotoarParser). Warnings are one line
`photoar: warning: <message>` (LogFormatter).
"""
from __future__ import annotations

import argparse
import functools
import importlib
import logging
import math
import re
import sys
import typing
from importlib import resources
from pathlib import Path

from app.engine import LIGHTING, EngineParams, Mode, SunSource
from app.units import srgb_hex

log = logging.getLogger("photoar")

# Sub-commands that live in their own module. Each module defines `register(sub)`, which adds
# its parser and sets `run=<callable(args) -> int>` with `set_defaults`; errors are raised as
# ValueError / FileNotFoundError / RuntimeError with a message that names the file.
COMMAND_MODULES: tuple[str, ...] = (
    "app.evaluate",
    "app.cmd_reconstruct",
    "app.cmd_hdr",
    "app.cmd_probe",
    "app.cmd_calibrate",
    "app.cmd_model",
    "app.cmd_reference",
    "app.cmd_metrics",
    "app.cmd_tonemap",
    "app.cmd_gui",
    "app.cmd_scene",
    "app.cmd_batch",
)


def _number(s: str, kind: type = float) -> float:
    """`s` as a finite int or float; ArgumentTypeError naming the value otherwise."""
    try:
        v = kind(s)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected {'an integer' if kind is int else 'a number'}, got {s!r}") from None
    if not math.isfinite(v):
        raise argparse.ArgumentTypeError(f"expected a finite number, got {s!r}")
    return v


def _finite_float(s: str) -> float:
    """argparse type: a finite number (no nan, inf)."""
    return _number(s)


def _positive_int(s: str) -> int:
    v = _number(s, int)
    if v < 1:
        raise argparse.ArgumentTypeError(f"must be at least 1, got {v}")
    return v


def _fraction(s: str) -> float:
    v = _number(s)
    if not 0.0 < v <= 1.0:
        raise argparse.ArgumentTypeError(f"must be in (0, 1], got {v}")
    return v


def _positive_float(s: str) -> float:
    v = _number(s)
    if not v > 0:
        raise argparse.ArgumentTypeError(f"must be positive, got {v}")
    return v


def xyz_arg(s: str) -> tuple[float, float, float]:
    """argparse type of a point, vector or colour given as "X,Y,Z" (or "R,G,B"): three finite
    numbers. The option's name is added by argparse, so the message names no axis letters."""
    try:
        v = tuple(float(x) for x in s.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected three comma-separated numbers, got {s!r}") from None
    if len(v) != 3:
        raise argparse.ArgumentTypeError(f"expected three comma-separated numbers, got {len(v)} in {s!r}")
    if not all(math.isfinite(x) for x in v):
        raise argparse.ArgumentTypeError(f"expected three finite numbers, got {s!r}")
    return v  # type: ignore[return-value]


QUIET_HELP = "no progress bars or log lines"
VERBOSE_HELP = ("also photoar's debug lines: cache hits, the captured radiance mesh's, photo light's and the "
                "sun estimate's whole records")


class PhotoarParser(argparse.ArgumentParser):
    """photoar's argument parser, for the top level and (as their parser class) every subcommand.

    * An argparse error is one line `<prog>: error: <problem> (<prog> --help)` on stderr and exit
      status 2, with <prog> the subcommand that failed (`photoar composite`), not the usage block.
    * A token that starts with '-' and a digit ("-0.74,0.62,0.27", "-1e-3") is an option's value,
      not an unknown option: `--sun-direction -0.74,0.62,0.27` works as with '='.
    * `-q/--quiet` and `-v/--verbose` are accepted after the subcommand too (`photoar composite ... -q`).
    """

    def __init__(self, *args, top: "PhotoarParser | None" = None, **kwargs):
        super().__init__(*args, **kwargs)
        self._negative_number_matcher = re.compile(r"^-\.?\d")  # as Python 3.13's argparse
        self._top = top if top is not None else self
        self._last = self  # top level: the deepest parser of the current parse (its errors are reported there)
        if top is not None:  # a subcommand: -q after it sets the top level's flag (absent: left as it is)
            self.add_argument("-q", "--quiet", action="store_true", default=argparse.SUPPRESS, help=QUIET_HELP)
            self.add_argument("-v", "--verbose", action="store_true", default=argparse.SUPPRESS, help=VERBOSE_HELP)

    def add_subparsers(self, **kwargs):
        kwargs.setdefault("parser_class", functools.partial(PhotoarParser, top=self._top))
        return super().add_subparsers(**kwargs)

    def parse_known_args(self, args=None, namespace=None):
        self._top._last = self
        return super().parse_known_args(args, namespace)

    def parse_args(self, args=None, namespace=None):
        ns, extra = self.parse_known_args(args, namespace)
        if extra:  # reported by the subcommand they follow
            self._last.error(f"unrecognized arguments: {' '.join(extra)}")
        return ns

    def error(self, message: str) -> typing.NoReturn:
        line = " ".join(str(message).split())
        self.exit(2, f"{self.prog}: error: {line} ({self.prog} --help)\n")


def _engine_arg(g, flag: str, name: str, **kw) -> None:
    """Option `flag` for EngineParams field `name`: its default is the field's, its help the field's
    documentation (EngineParams.doc), so the command line and the config cannot drift apart."""
    default = EngineParams.__dataclass_fields__[name].default
    shown = " (default %(default)s)" if default is not None else ""
    g.add_argument(flag, default=default, help=EngineParams.doc(name) + shown, **kw)


def _add_engine_args(p: argparse.ArgumentParser, passes: bool = True) -> None:
    g = p.add_argument_group("engine")
    _engine_arg(g, "--mode", "mode", choices=list(typing.get_args(Mode)))
    if passes:
        _engine_arg(g, "--passes", "passes", type=_positive_int)
    _engine_arg(g, "--fps", "fps", type=_positive_float)
    _engine_arg(g, "--source-fraction", "source_fraction", type=_fraction)
    _engine_arg(g, "--patch-size", "patch_size", type=_positive_float)
    _engine_arg(g, "--map-res", "map_res", type=_positive_int)
    add_lighting_arg(g, EngineParams().lighting)
    add_sun_arg(g)
    _engine_arg(g, "--specular", "specular", type=_finite_float)
    _engine_arg(g, "--shininess", "shininess", type=_finite_float)
    g.add_argument("--no-object-light", action="store_true", help="turn off: " + EngineParams.doc("object_light"))
    g.add_argument("--no-second-order", action="store_true", help="turn off: " + EngineParams.doc("second_order"))
    g.add_argument("--cache", type=Path, default=None,
                   help="folder for per-scene precompute (default $PHOTOAR_CACHE or ~/.cache/photoar)")
    g.add_argument("--device", default=None, help="Warp device, e.g. cpu or cuda:0 (default cpu)")


def add_lighting_arg(g, default: str = "known") -> None:
    """--lighting, with the choices and their meaning from app.engine.LIGHTING (one list, the
    documentation of EngineParams.lighting)."""
    g.add_argument("--lighting", choices=list(LIGHTING), default=default,
                   help=EngineParams.doc("lighting") + " (default %(default)s)")


def add_sun_arg(g) -> None:
    """--sun (EngineParams.sun): which sun lights a room with openings, the declared one or the estimate."""
    _engine_arg(g, "--sun", "sun", choices=list(typing.get_args(SunSource)))


def _params(a: argparse.Namespace) -> EngineParams:
    return EngineParams(mode=a.mode, passes=getattr(a, "passes", None), fps=a.fps, source_fraction=a.source_fraction, patch_size=a.patch_size,
                        map_res=a.map_res, specular=a.specular, shininess=a.shininess,
                        lighting=a.lighting, sun=a.sun,
                        object_light=not a.no_object_light, second_order=not a.no_second_order)


def add_object_args(p) -> None:
    """The object and its pose: one definition for `composite` and `gui`, so --place/--yaw mean the same."""
    p.add_argument("--object", type=Path, default=None,
                   help="object mesh (PLY/OBJ/GLB): at --place/--yaw, else at the scene's object pose")
    p.add_argument("--place", type=xyz_arg, default=None, metavar="X,Y,Z",
                   help="world point (m) for the bottom centre of the mesh's bounding box")
    p.add_argument("--yaw", type=_finite_float, default=0.0,
                   help="right-handed turn about +Y through the --place point, degrees (default %(default)s)")
    p.add_argument("--object-size", type=_positive_float, default=None,
                   help="largest extent of the object in metres (default: the file's units when they look like "
                        "metres, else 0.6 m)")
    colour = p.add_mutually_exclusive_group()
    colour.add_argument("--object-albedo", type=xyz_arg, default=None, metavar="R,G,B",
                        help="linear diffuse reflectance of --object in [0, 1] (default: the scene's "
                             "synthetic_object albedo for its own mesh, else 0.6 grey)")
    colour.add_argument("--object-colour", "--object-color", dest="object_albedo", type=srgb_hex, metavar="#RRGGBB",
                        help="the same as an sRGB hex colour, e.g. '#b4966a' (converted to linear reflectance)")


def run_composite(a: argparse.Namespace, **kw) -> dict:
    """`photoar composite` on its parsed arguments `a` (also each job of `photoar batch`); `kw`
    goes to app.composite.main (make_engine). Returns the report."""
    from app import composite

    return composite.main(a.scene, a.out, _params(a), cache_dir=a.cache, object_mesh=a.object, quiet=a.quiet,
                          device=a.device, place=a.place, yaw=a.yaw, object_size=a.object_size,
                          placement=a.placement, work_res=a.work_res, object_albedo=a.object_albedo, **kw)


def build_parser() -> argparse.ArgumentParser:
    ap = PhotoarParser(prog="photoar", description="Insert synthetic objects into photographs of rooms, "
                       "lit by the room's light and casting soft shadows.")
    ap.add_argument("-q", "--quiet", action="store_true", help=QUIET_HELP)
    ap.add_argument("-v", "--verbose", action="store_true", help=VERBOSE_HELP)
    sub = ap.add_subparsers(dest="command", required=True)

    c = sub.add_parser("composite", help="composite a scene's synthetic object into its photo")
    c.add_argument("scene", type=Path, help="scene folder (scene.json, background.png, object mesh)")
    c.add_argument("--out", type=Path, required=True, help="output folder")
    add_object_args(c)
    c.add_argument("--placement", type=Path, default=None,
                   help="placement JSON saved by `photoar gui` (mesh, position, yaw, lift, scale)")
    c.add_argument("--work-res", type=int, default=None, metavar="PX",
                   help="the engine works at most PX pixels on the long side; the composite is written at the "
                        "photo's full resolution (default 1024; 0: work at the photo's own resolution)")
    _add_engine_args(c)

    d = sub.add_parser("demo", help="composite the bundled demo scene and print where the picture is")
    d.add_argument("--out", type=Path, default=Path("out/demo"), help="output folder (default %(default)s)")
    _add_engine_args(d)

    for name in COMMAND_MODULES:
        importlib.import_module(name).register(sub)
    return ap


class LogFormatter(logging.Formatter):
    """photoar's log lines: info as the bare message; a warning as one line `photoar: warning:
    <message>`; an error as one line `photoar: error: <message>` (log.exception's exception as
    `: <its message>`, no traceback)."""

    def format(self, record: logging.LogRecord) -> str:
        msg = record.getMessage()
        if record.levelno >= logging.ERROR:
            msg = f"photoar: error: {msg}"
            if record.exc_info and record.exc_info[1] is not None:
                msg += f": {' '.join(str(record.exc_info[1]).split())}"
        elif record.levelno >= logging.WARNING:
            msg = f"photoar: warning: {msg}"
        return msg


def log_handler() -> logging.Handler:
    """The stderr handler of the command line's log (LogFormatter)."""
    h = logging.StreamHandler(sys.stderr)
    h.setFormatter(LogFormatter())
    return h


def demo_scene_dir() -> Path:
    return Path(str(resources.files("app") / "demo"))


def main(argv: list[str] | None = None) -> int:
    ap = build_parser()
    a = ap.parse_args(argv)
    logging.basicConfig(level=logging.WARNING if a.quiet else logging.INFO, handlers=[log_handler()])
    if a.verbose and not a.quiet:  # photoar's own debug lines only, not every library's
        logging.getLogger("photoar").setLevel(logging.DEBUG)
    from kernels import runtime
    from recon.scene import SceneError

    try:
        runtime.device(getattr(a, "device", None))
        if getattr(a, "run", None) is not None:
            return int(a.run(a) or 0)
        params = _params(a)
        from app import composite

        if a.command == "composite":
            run_composite(a)
            print(a.out / "composite.png")
        elif a.command == "demo":
            composite.main(demo_scene_dir(), a.out, params, cache_dir=a.cache or a.out.parent / ".cache",
                           quiet=a.quiet, device=a.device)
            print(a.out / "composite.png")  # as composite: the path on stdout, the timings in the log line
        return 0
    except (SceneError, FileNotFoundError, RuntimeError, ValueError) as e:
        print(f"photoar: error: {e}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
