"""``usdbake sky``: a layer over the input with a sky model as a DomeLight and the sun as a DistantLight."""

from __future__ import annotations

import argparse

from rich.console import Console

from ..core.errors import UsageError
from ..stages.inputs import open_source
from .console import EXIT_OK

SKY_SITE = (41.98, 2.82, 1.0)
"""``usdbake sky``'s place without --weather or --latitude/--longitude/--timezone (Girona)."""


def _number(low: float, high: float):
    """An argparse type: a finite number in [low, high] (NaN, inf and out-of-range values are one-line errors).
    Irradiance bounds: the solar constant is 1361 W/m^2, so no measured DNI exceeds 1500 nor DHI 1000."""
    def parse(text: str) -> float:
        try:
            value = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None
        if not low <= value <= high:  # False for NaN too
            raise argparse.ArgumentTypeError(f"{text} is outside {low:g}..{high:g}")
        return value
    return parse


def _instant(text: str) -> str:
    """An argparse type: an ISO 8601 date-time (``2026-06-21T12:00``), checked here rather than after the stage
    is read."""
    from ..stages.sky_dome import check_sky_time

    try:
        check_sky_time(text)
    except ValueError as error:
        raise argparse.ArgumentTypeError(str(error)) from None
    return text


def add_parser(commands) -> None:
    sky = commands.add_parser("sky", help="write a layer over the input with a sky model as a DomeLight and a sun "
                              "DistantLight, so radiosity, probes and grids are daylit")
    sky.add_argument("input")
    sky.add_argument("-o", "--output", required=True, help="the sky layer (.usd, .usda or .usdc); a lat-long "
                     ".exr is written beside it")
    sky.add_argument("--weather", help="typical-year weather file (.epw, TMY3 .csv): the place, and the Perez "
                     "sky of the hour holding --time (its year ignored)")
    sky.add_argument("--model", choices=("preetham", "perez", "overcast"),
                     help="sky model (default: perez with --weather, else preetham)")
    sky.add_argument("--time", default="2026-06-21T12:00", type=_instant, help="ISO 8601 local standard time")
    sky.add_argument("--latitude", type=_number(-90, 90), help=f"degrees north (default {SKY_SITE[0]}, or the "
                     "weather file's)")
    sky.add_argument("--longitude", type=_number(-180, 180), help=f"degrees east (default {SKY_SITE[1]}, or the "
                     "weather file's)")
    sky.add_argument("--timezone", type=_number(-12, 14), help=f"hours east of UTC (default {SKY_SITE[2]:g}, or "
                     "the weather file's)")
    sky.add_argument("--north", type=_number(-360, 360), default=0.0, help="degrees from the stage's default north")
    sky.add_argument("--turbidity", type=_number(1, 64), default=3.0, help="Preetham turbidity")
    sky.add_argument("--dni", type=_number(0, 1500), help="Perez: direct normal irradiance, W/m^2 (default 600, "
                     "or the weather file's)")
    sky.add_argument("--dhi", type=_number(0, 1000), help="Perez: diffuse horizontal irradiance, W/m^2 (default "
                     "150, or the weather file's)")
    sky.add_argument("--ground-albedo", type=_number(0, 1), default=0.2, help="the grey ground below the horizon")
    sky.add_argument("--efficacy", choices=("perez", "179"), default="perez",
                     help="Perez: solar W/m^2 to light by the Perez et al. 1990 luminous efficacy (perez, as "
                     "gendaymtx -O0; default) or by Radiance's 179 lm/W (179, as gendaymtx -O1)")


def cmd_sky(args, console: Console) -> int:
    from ..stages.sky_dome import make_sky, weather_hour

    site = dict(zip(("latitude", "longitude", "timezone"), SKY_SITE))
    irradiance = {"direct_normal": 600.0, "diffuse_horizontal": 150.0}
    model = args.model or ("perez" if args.weather else "preetham")
    hour = ""
    if args.weather:
        site, irradiance, hour = weather_hour(args.weather, args.time)
        if model != "perez":
            raise UsageError(f"--model {model} --weather {args.weather}: a weather file gives a Perez sky "
                             f"(its direct and diffuse irradiance); drop --model or use --model perez")
    for key in site:
        given = getattr(args, key)
        if given is not None:
            if args.weather and abs(given - site[key]) > 1e-6:
                raise UsageError(f"--{key} {given:g} disagrees with {args.weather}'s {site[key]:g}: the weather "
                                 f"file gives the place; drop --{key}")
            site[key] = given
    for key, option in (("direct_normal", "dni"), ("diffuse_horizontal", "dhi")):
        if getattr(args, option) is not None:
            if args.weather:
                raise UsageError(f"--{option} with --weather: the weather file gives the irradiance; drop --{option}")
            irradiance[key] = getattr(args, option)
    if not -90.0 <= site["latitude"] <= 90.0:
        raise UsageError(f"--latitude {site['latitude']}: outside -90..90")
    if not -12.0 <= site["timezone"] <= 14.0:
        raise UsageError(f"--timezone {site['timezone']}: not a time zone (-12..14 hours)")
    source, _ = open_source(args.input)
    written, sky = make_sky(source, args.output, model, args.time, **site, north=args.north,
                            turbidity=args.turbidity, **irradiance, ground_albedo=args.ground_albedo,
                            efficacy=args.efficacy)
    sun = float(sky.sun_irradiance[1]) if sky.sun_world is not None else 0.0
    print(f"wrote {written[0]} and {written[1]}: {hour}diffuse horizontal {sky.diffuse_horizontal:.1f} W/m^2, "
          f"sun {sun:.1f} W/m^2 normal (visible-equivalent: x 179 = lux)")
    return EXIT_OK
