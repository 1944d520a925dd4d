"""``usdbake preview``: render a (baked) stage to an image (usdbake.preview)."""

from __future__ import annotations

import json

from rich.console import Console

from .console import EXIT_OK


def add_parser(commands) -> None:
    preview = commands.add_parser("preview", help="render a (baked) stage to an image: AO, daylight, irradiance")
    preview.add_argument("input", help="stage to render, e.g. a usdbake output")
    preview.add_argument("-o", "--output", required=True, help="image to write (.png, or .exr for float data)")
    view = preview.add_mutually_exclusive_group()
    view.add_argument("--camera", metavar="PATH", help="UsdGeom.Camera prim to look through")
    view.add_argument("--auto-camera", action="store_true", help="three-quarter view framing the stage (default)")
    preview.add_argument("--orbit", nargs=2, type=float, metavar=("AZ", "EL"),
                         help="auto camera azimuth and elevation in degrees (default: best of four views)")
    preview.add_argument("--channel", metavar="NAME", help="baked primvar to show: ao, daylight, irradiance, "
                         "A+B, NAME[k], or a full primvars:... name (default: albedo only)")
    preview.add_argument("--time", type=float, default=None, help="time code (default: default time)")
    preview.add_argument("--size", default="640x480", metavar="WxH", help="image size (default 640x480)")
    preview.add_argument("--exposure", type=float, default=None, metavar="EV",
                         help="exposure in stops for shaded channels (default: automatic)")
    preview.add_argument("--style", default="auto", choices=("auto", "falsecolor", "shaded"),
                         help="false colour for scalars, shading for colours (auto) or forced")
    preview.add_argument("--range", nargs=2, type=float, metavar=("LO", "HI"), help="false-colour scale range")
    preview.add_argument("--no-legend", action="store_true", help="no legend bar beside false colour")
    preview.add_argument("--wire", action="store_true", help="overlay the edges of the authored polygons")
    preview.add_argument("--probes", action="store_true", help="draw LightProbeCloud probes as spheres")
    preview.add_argument("--grid", action="store_true", help="draw IrradianceVectorGrid vertices as spheres")
    preview.add_argument("--compare", metavar="A.png", help="write [A | this | difference] and print the RMS")
    preview.add_argument("--device", default="cpu", help="Warp device: cpu (default) or cuda:N")
    preview.add_argument("--json", action="store_true", help="machine-readable report on stdout")


def cmd_preview(args, console: Console) -> int:
    from ..preview.compose import parse_size, preview

    report = preview(args.input, args.output, camera=args.camera, channel=args.channel, time=args.time,
                     size=parse_size(args.size), exposure=args.exposure, style=args.style,
                     value_range=tuple(args.range) if args.range else None, legend=not args.no_legend,
                     wire=args.wire, probes=args.probes, grid=args.grid, compare=args.compare,
                     orbit=tuple(args.orbit) if args.orbit else None, device=args.device)
    report.pop("image", None)
    if args.json:
        print(json.dumps(report, indent=2, default=str))
        return EXIT_OK
    for message in report["messages"]:
        console.print(f"[yellow]note:[/yellow] {message}", highlight=False)
    if "rms" in report:
        print(f"RMS difference: {report['rms']:.6f}")
    console.print(f"wrote {args.output} ({report['mode']}, camera {report['camera']}) in "
                  f"{report['seconds']:.2f} s", highlight=False)
    return EXIT_OK
