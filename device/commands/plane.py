"""`laserpi plane`: a laser plane z = a x + b y + c to triangulation parameters and back
(thesis section 3.2.2, appendix D.2.2). An adapter only: the conversions are
``device.model.triangulation.params_from_plane`` / ``plane_from_params``. At this command C and
c are in mm (as the thesis quotes its planes) and the angles in degrees.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import warnings

from host_sdk.commands.argtypes import finite_float


def _three(text: str) -> tuple[float, float, float]:
    parts = text.split(",")
    if len(parts) != 3:
        raise argparse.ArgumentTypeError(f"expected A,B,C (three numbers), got {text!r}")
    return tuple(finite_float(p) for p in parts)  # type: ignore[return-value]


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--plane", type=_three, metavar="A,B,C",
                        help="plane z = A x + B y + C in the OpenCV camera frame, C in mm (write --plane=A,B,C when A is negative)")
    parser.add_argument("--beta-deg", type=finite_float, default=90.0, help="laser rotation w.r.t. s (default 90)")
    parser.add_argument("--alpha-deg", type=finite_float, help="camera rotation w.r.t. s")
    parser.add_argument("--psi-deg", type=finite_float, help="laser roll (90 = line along the image rows)")
    parser.add_argument("--s-mm", type=finite_float, help="baseline s")
    parser.add_argument("--json", action="store_true", help="print one JSON object")
    parser.set_defaults(_parser=parser)


def run(args: argparse.Namespace) -> int:
    from device.model.triangulation import (DegeneratePlaneError, LaserPlane, TriangulationParams, check_conditioning,
                                            params_from_plane, plane_from_params)

    parser = args._parser
    given = [name for name in ("alpha_deg", "psi_deg", "s_mm") if getattr(args, name) is not None]
    if args.plane is not None:
        if given:
            parser.error(f"argument --plane: not allowed with --{given[0].replace('_', '-')}")
        a, b, c_mm = args.plane
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                for reason in check_conditioning(LaserPlane.from_abc(a, b, c_mm * 1e-3)):
                    print(f"laserpi plane: warning: {reason}", file=sys.stderr)
            p = params_from_plane(a, b, c_mm * 1e-3, math.radians(args.beta_deg))
        except DegeneratePlaneError as exc:
            parser.error(f"argument {'--beta-deg' if 'beta' in str(exc) else '--plane'}: {exc}")
        out = {"theta_deg": math.degrees(p.theta), "alpha_deg": math.degrees(p.alpha),
               "psi_deg": math.degrees(p.psi), "s_mm": p.s * 1e3}
    else:
        missing = [name for name in ("alpha_deg", "psi_deg", "s_mm") if name not in given]
        if missing:
            parser.error("give --plane A,B,C, or all of --alpha-deg, --psi-deg and --s-mm; missing "
                         + ", ".join("--" + m.replace("_", "-") for m in missing))
        p = TriangulationParams(math.radians(args.alpha_deg), math.radians(args.beta_deg),
                                math.radians(args.psi_deg), args.s_mm * 1e-3)
        try:
            a, b, c = plane_from_params(p)
        except DegeneratePlaneError as exc:
            parser.error(f"argument --alpha-deg/--beta-deg/--psi-deg/--s-mm: {exc}")
        out = {"a": a, "b": b, "c": c * 1e3}
    if args.json:
        print(json.dumps(out))
    else:
        for key, value in out.items():
            print(f"{key:<10} {value:.6f}")
    return 0
