// usdbake viewer sky: the sun position, sky models and daylight weights of the Python library, in the browser.
//
// A float64 port (Math.*) of kernels/solar.py (sun_position, horizontal_position, refraction, day_of_year,
// SunPosition.enu), kernels/sky.py (patch_radiance and the preetham, perez, overcast and uniform models,
// sun_normal_irradiance, air_mass), kernels/luminous_efficacy.py (perez_efficacy) and the daylight relighting
// helpers (visible_factors, sun_normal, sky_weights, horizontal_cosines, sun_patch_weights, ground_radiance;
// kernels/daylight_relight.py, formerly processors/daylight/daylight.py and interreflection.py). Same constants,
// same order of operations where it matters; tests/stages/test_viewer_sky.py holds it to the Python to 1e-6.
//
// A plain script: <script src="sky.js"> defines the functions as globals; in Node (vm or require) they are
// also exported through module.exports. Private helpers start with "sky" to keep clear of other scripts'
// globals.
//
// Frames and units as the Python: ENU (x east, y north, z up), azimuth from north towards east, angles in
// degrees unless said otherwise, radiance in visible-equivalent W/(m^2 sr) (luminance / 179 lm/W).
// Patch samples are passed as data: `samples` is patch_samples(patches, 3) flattened, a Float32Array or
// Float64Array of N * S * 3 (S = 9 samples per patch, each an ENU unit direction).
"use strict";

const SKY_DEG2RAD = Math.PI / 180.0;  // numpy's radians: x * (pi / 180)
const SKY_RAD2DEG = 180.0 / Math.PI;  // numpy's degrees: x * (180 / pi)
const SKY_DAY_MS = 86400000;
const SKY_J2000_US = 946728000000000;  // 2000-01-01T12:00 UTC (Julian day 2451545.0), microseconds since 1970

function skyMod(a, b) {
  // numpy's float mod (npy_divmod): the sign of the divisor, as Python's %.
  let mod = a % b;
  if (mod !== 0) {
    if ((b < 0) !== (mod < 0)) mod += b;
  } else {
    mod = b < 0 ? -0 : 0;
  }
  return mod;
}

function skyClip(x, lo, hi) {
  return Math.min(Math.max(x, lo), hi);
}

function skyNorm(v) {
  return Math.sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]);
}

function skyUnit(v) {
  const n = skyNorm(v);
  return [v[0] / n, v[1] / n, v[2] / n];
}

function skyFinite(value, fallback) {
  return Number.isFinite(value) ? value : fallback;
}

// ---------------------------------------------------------------------------
// kernels/solar.py: NOAA Solar Calculator (after Meeus, "Astronomical Algorithms", 1991)

function dayOfYear(localMs) {
  // day_of_year: 1 = 1 January, of the local clock given as Date.UTC(y, m - 1, d, h, min).
  const days = Math.floor(localMs / SKY_DAY_MS);
  const year = new Date(days * SKY_DAY_MS).getUTCFullYear();
  return days - Date.UTC(year, 0, 1) / SKY_DAY_MS + 1;
}

function julianDay(utcMs) {
  // julian_day of a UTC instant in milliseconds since 1970 (whole microseconds, as datetime64[us]).
  return 2451545.0 + (Math.round(utcMs * 1000) - SKY_J2000_US) / 86400e6;
}

function refraction(elevationDeg, pressureMbar = 1010.0, temperatureC = 10.0) {
  // NOAA's refraction correction (degrees) for a true elevation, scaled by P/1010 * 283/(273 + T).
  const e = elevationDeg;
  const t = Math.tan(e * SKY_DEG2RAD);
  let arcsec;
  if (e > 85.0) arcsec = 0.0;
  else if (e > 5.0) arcsec = 58.1 / t - 0.07 / Math.pow(t, 3) + 0.000086 / Math.pow(t, 5);
  else if (e > -0.575) arcsec = 1735.0 + e * (-518.2 + e * (103.4 + e * (-12.79 + e * 0.711)));
  else arcsec = -20.772 / t;
  return arcsec / 3600.0 * (pressureMbar / 1010.0) * (283.0 / (273.0 + temperatureC));
}

function horizontalPosition(latitude, declination, hourAngle, options = {}) {
  // horizontal_position: {zenith, azimuth} (degrees, azimuth from north towards east) of the sun at
  // declination and hour angle: cos(zenith) = sin(lat) sin(dec) + cos(lat) cos(dec) cos(H), refracted.
  const pressure = options.pressureMbar ?? 1010.0, temperature = options.temperatureC ?? 10.0;
  const refract = options.refract ?? true;
  const lat = latitude * SKY_DEG2RAD, dec = declination * SKY_DEG2RAD, ha = hourAngle * SKY_DEG2RAD;
  const cosZenith = skyClip(Math.sin(lat) * Math.sin(dec) + Math.cos(lat) * Math.cos(dec) * Math.cos(ha), -1.0, 1.0);
  let zenith = Math.acos(cosZenith) * SKY_RAD2DEG;
  // Azimuth from south towards west is atan2(sin H, cos H sin(lat) - tan(dec) cos(lat)); +180 -> from north.
  const azimuth = skyMod(Math.atan2(Math.sin(ha), Math.cos(ha) * Math.sin(lat) - Math.tan(dec) * Math.cos(lat))
                         * SKY_RAD2DEG + 180.0, 360.0);
  if (refract) zenith = zenith - refraction(90.0 - zenith, pressure, temperature);
  return {zenith, azimuth};
}

function sunEnu(zenith, azimuth) {
  // SunPosition.enu: unit vector toward the sun (east, north, up) from zenith and azimuth in degrees.
  const alt = (90.0 - zenith) * SKY_DEG2RAD, az = azimuth * SKY_DEG2RAD;
  return [Math.sin(az) * Math.cos(alt), Math.cos(az) * Math.cos(alt), Math.sin(alt)];
}

function sunPosition(localMs, latitude, longitude, timezone = 0.0, options = {}) {
  // sun_position at the local standard time localMs (Date.UTC of the local clock), latitude degrees north,
  // longitude degrees east, timezone hours east of UTC: the sun's geometric mean longitude L0, mean anomaly
  // M and eccentricity e in Julian centuries since J2000, the equation of centre, the apparent longitude,
  // the corrected obliquity, the declination and the equation of time (Smart's series in
  // y = tan^2(obliquity / 2)); the true solar time gives the hour angle. Returns
  // {zenith, azimuth, declination, equationOfTime (minutes), hourAngle, enu: [e, n, u]}.
  const localUs = Math.round(localMs * 1000);
  const utcUs = localUs - Math.round(timezone * 3600e6);
  const jc = ((2451545.0 + (utcUs - SKY_J2000_US) / 86400e6) - 2451545.0) / 36525.0;
  const rad = SKY_DEG2RAD;
  const l0 = skyMod(280.46646 + jc * (36000.76983 + jc * 0.0003032), 360.0);
  const m = 357.52911 + jc * (35999.05029 - 0.0001537 * jc);
  const e = 0.016708634 - jc * (0.000042037 + 0.0000001267 * jc);
  const center = (Math.sin(m * rad) * (1.914602 - jc * (0.004817 + 0.000014 * jc))
                  + Math.sin((2 * m) * rad) * (0.019993 - 0.000101 * jc) + Math.sin((3 * m) * rad) * 0.000289);
  const trueLong = l0 + center;
  const omega = 125.04 - 1934.136 * jc;
  const apparentLong = trueLong - 0.00569 - 0.00478 * Math.sin(omega * rad);
  const meanObliquity = 23.0 + (26.0 + (21.448 - jc * (46.815 + jc * (0.00059 - jc * 0.001813))) / 60.0) / 60.0;
  const obliquity = meanObliquity + 0.00256 * Math.cos(omega * rad);
  const declination = Math.asin(Math.sin(obliquity * rad) * Math.sin(apparentLong * rad)) * SKY_RAD2DEG;
  const ty = Math.tan((obliquity / 2.0) * rad);
  const y = ty * ty;
  const eot = 4.0 * ((y * Math.sin(2 * (l0 * rad)) - 2 * e * Math.sin(m * rad)
                      + 4 * e * y * Math.sin(m * rad) * Math.cos(2 * (l0 * rad))
                      - 0.5 * y * y * Math.sin(4 * (l0 * rad)) - 1.25 * e * e * Math.sin(2 * (m * rad))) * SKY_RAD2DEG);
  let dayUs = localUs % 86400e6;  // exact (fmod); datetime64[D] floors
  if (dayUs < 0) dayUs += 86400e6;
  const minutes = dayUs / 60e6;
  const trueSolar = skyMod(minutes + eot + 4.0 * longitude - 60.0 * timezone, 1440.0);
  const hourAngle = trueSolar / 4.0 - 180.0;
  const {zenith, azimuth} = horizontalPosition(latitude, declination, hourAngle, options);
  return {zenith, azimuth, declination, equationOfTime: eot, hourAngle, enu: sunEnu(zenith, azimuth)};
}

// ---------------------------------------------------------------------------
// kernels/sky.py: sky models (ENU directions; the sun an ENU vector)

const LUMINOUS_EFFICACY = 179.0;  // lm/W: Radiance's white efficacy
const EXTRATERRESTRIAL_ILLUMINANCE = 133800.0;  // lux at mean Earth-Sun distance (Darula, Hooper & Kittler 2005)
const RGB_WAVELENGTHS_UM = [0.680, 0.550, 0.440];  // standing for R, G, B in the sun's transmittance
const XYZ_TO_SRGB = [[3.2404542, -1.5371385, -0.4985314],
                     [-0.9692660, 1.8760108, 0.0415560],
                     [0.0556434, -0.2040259, 1.0572252]];

// The model tables (Perez, Seals & Michalsky 1993 Table 1 with its erratum; Perez et al. 1990 Table 4) come
// from the kernels, not from a copy here: the daylight stream's header carries them (kernels/daylight_relight.
// sky_model_tables), and setSkyTables takes them before any sky is evaluated.
let SKY_TABLES = null;

function setSkyTables(tables) {
  // {perez_coefficients: 160 numbers [bin][parameter][k], perez_clearness_edges: 7, efficacy_clearness_edges: 7,
  //  efficacy_diffuse: 8 rows of 4, efficacy_direct: 8 rows of 4}
  SKY_TABLES = tables;
}

function skyTables() {
  if (!SKY_TABLES) throw new Error("sky.js: setSkyTables() has not been given the kernels' tables");
  return SKY_TABLES;
}

const SOLAR_CONSTANT = 1367.0;  // W/m^2 at the mean Earth-Sun distance

function skyPerez(cosTheta, gamma, c) {
  // _perez: Perez function of Preetham et al. 1999 (cos theta held at 0.01, where Perez diverges).
  cosTheta = Math.max(cosTheta, 0.01);
  const cg = Math.cos(gamma);
  return (1 + c[0] * Math.exp(c[1] / cosTheta)) * (1 + c[2] * Math.exp(c[3] * gamma) + c[4] * (cg * cg));
}

function skyPreethamState(sun, turbidity) {
  // Preetham, Shirley & Smits 1999, Appendix A.2: Perez coefficients of Y, x, y linear in turbidity, the
  // zenith luminance and chromaticity; null when the sun is below the horizon (the sky is black there).
  const t = +turbidity;
  const s = skyUnit(sun);
  if (s[2] <= 0.0) return null;
  const thetaS = Math.acos(Math.min(1.0, s[2]));
  const coeffY = [0.1787 * t - 1.4630, -0.3554 * t + 0.4275, -0.0227 * t + 5.3251, 0.1206 * t - 2.5771,
                  -0.0670 * t + 0.3703];
  const coeffX = [-0.0193 * t - 0.2592, -0.0665 * t + 0.0008, -0.0004 * t + 0.2125, -0.0641 * t - 0.8989,
                  -0.0033 * t + 0.0452];
  const coeffYc = [-0.0167 * t - 0.2608, -0.0950 * t + 0.0092, -0.0079 * t + 0.2102, -0.0441 * t - 1.6537,
                   -0.0109 * t + 0.0529];
  const chi = (4.0 / 9.0 - t / 120.0) * (Math.PI - 2 * thetaS);
  const zenithY = Math.max(0.0, (4.0453 * t - 4.9710) * Math.tan(chi) - 0.2155 * t + 2.4192) * 1000.0;  // cd/m^2
  const tVec = [t * t, t, 1.0];
  const th = [Math.pow(thetaS, 3), Math.pow(thetaS, 2), thetaS, 1.0];
  const chroma = (m) => {  // t_vec @ m @ th
    let out = 0.0;
    for (let j = 0; j < 4; j++) out += (tVec[0] * m[0][j] + tVec[1] * m[1][j] + tVec[2] * m[2][j]) * th[j];
    return out;
  };
  const zenithX = chroma([[0.00166, -0.00375, 0.00209, 0.0], [-0.02903, 0.06377, -0.03202, 0.00394],
                          [0.11693, -0.21196, 0.06052, 0.25886]]);
  const zenithYc = chroma([[0.00275, -0.00610, 0.00317, 0.0], [-0.04214, 0.08970, -0.04153, 0.00516],
                           [0.15346, -0.26756, 0.06670, 0.26688]]);
  return {sun: s, coeffY, coeffX, coeffYc, zenithY, zenithX, zenithYc,
          normY: skyPerez(1.0, thetaS, coeffY), normX: skyPerez(1.0, thetaS, coeffX),
          normYc: skyPerez(1.0, thetaS, coeffYc)};
}

function skyXyyToRgb(x, y, bigY, out, offset) {
  // _xyy_to_rgb: xyY -> XYZ -> linear sRGB (D65), negative channels clipped; added into out[offset..+2].
  y = Math.max(y, 1e-6);
  const X = x / y * bigY, Z = (1 - x - y) / y * bigY;
  for (let c = 0; c < 3; c++) {
    const m = XYZ_TO_SRGB[c];
    out[offset + c] = Math.max(X * m[0] + bigY * m[1] + Z * m[2], 0.0);
  }
}

function preethamRadiance(direction, sun, turbidity = 3.0) {
  // preetham_radiance of one ENU direction: [r, g, b] W/(m^2 sr) (luminance / 179); black below the horizon.
  const state = skyPreethamState(sun, turbidity);
  const out = [0.0, 0.0, 0.0];
  if (state) skyPreethamAt(state, direction[0], direction[1], direction[2], out, 0);
  return out;
}

function skyPreethamAt(state, dx, dy, dz, out, offset) {
  const s = state.sun;
  const cosTheta = dz;
  if (!(cosTheta >= 0.0)) {
    out[offset] = out[offset + 1] = out[offset + 2] = 0.0;
    return;
  }
  const gamma = Math.acos(skyClip(dx * s[0] + dy * s[1] + dz * s[2], -1.0, 1.0));
  const bigY = state.zenithY * (skyPerez(cosTheta, gamma, state.coeffY) / state.normY);
  const x = state.zenithX * (skyPerez(cosTheta, gamma, state.coeffX) / state.normX);
  const y = state.zenithYc * (skyPerez(cosTheta, gamma, state.coeffYc) / state.normYc);
  skyXyyToRgb(x, y, bigY, out, offset);
  for (let c = 0; c < 3; c++) out[offset + c] /= LUMINOUS_EFFICACY;
}

function overcastRadiance(direction, sun) {
  // overcast_radiance: CIE overcast sky, L = Lz (1 + 2 cos theta) / 3, Lz = 8.6 sin(sun altitude) + 0.123
  // kcd/m^2 (gensky -c), grey [v, v, v].
  const s = skyUnit(sun);
  const zenith = (8.6 * Math.max(s[2], 0.0) + 0.123) * 1000.0 / LUMINOUS_EFFICACY;
  const value = zenith * (1 + 2 * Math.max(direction[2], 0.0)) / 3.0;
  return [value, value, value];
}

function airMass(cosZenith) {
  // air_mass (kernels/sky.py): relative optical air mass, Kasten (1966), finite at the horizon; Infinity
  // from 93.885 degrees.
  const zenithDeg = Math.acos(Math.min(1.0, Math.max(-1.0, cosZenith))) * SKY_RAD2DEG;
  if (zenithDeg >= 93.885) return Infinity;
  return 1.0 / (Math.max(cosZenith, 0.0) + 0.15 * Math.pow(93.885 - zenithDeg, -1.253));
}

function sunNormalIrradiance(sun, turbidity = 3.0, dayOfYear = 172) {
  // sun_normal_irradiance: [r, g, b] direct normal irradiance (W/m^2, illuminance / 179): the extraterrestrial
  // illuminance with the Earth-Sun distance correction times Preetham's Rayleigh and aerosol (Angstrom,
  // beta = 0.04608 T - 0.04586, alpha = 1.3) transmittances; zero below the horizon.
  const s = skyUnit(sun);
  if (s[2] <= 0.0) return [0.0, 0.0, 0.0];
  const m = airMass(s[2]);
  const beta = Math.max(0.0, 0.04608 * turbidity - 0.04586);
  const distance = 1.0 + 0.033 * Math.cos(2 * Math.PI * dayOfYear / 365.0);
  return RGB_WAVELENGTHS_UM.map((lam) => {
    const transmittance = Math.exp(-0.008735 * Math.pow(lam, -4.08) * m) * Math.exp(-beta * Math.pow(lam, -1.3) * m);
    return EXTRATERRESTRIAL_ILLUMINANCE * distance / LUMINOUS_EFFICACY * transmittance;
  });
}

function perezSkyState(sunZenith, directNormal, diffuseHorizontal, dayOfYear = 172) {
  // perez_sky_state: [epsilon, Delta], sky clearness and brightness (Perez et al. 1990) from DNI and DHI
  // (W/m^2), sunZenith in radians; clamped to epsilon 1..12, Delta 0.01..0.6 as gendaylit.
  const z = +sunZenith;
  const dhi = Math.max(+diffuseHorizontal, 1e-9);
  const kappaZ3 = 1.041 * Math.pow(z, 3);
  const epsilon = ((dhi + Math.max(+directNormal, 0.0)) / dhi + kappaZ3) / (1.0 + kappaZ3);
  const extraterrestrial = SOLAR_CONSTANT * (1.0 + 0.033 * Math.cos(2 * Math.PI * dayOfYear / 365.0));
  const delta = Math.min(airMass(Math.cos(z)), 40.0) * dhi / extraterrestrial;
  return [skyClip(epsilon, 1.0, 12.0), skyClip(delta, 0.01, 0.6)];
}

function skySearchRight(edges, value) {
  // numpy searchsorted(edges, value, side="right"): how many edges are <= value.
  let k = 0;
  while (k < edges.length && edges[k] <= value) k++;
  return k;
}

function perezCoefficients(sunZenith, epsilon, delta) {
  // perez_coefficients: [a, b, c, d, e] of the all-weather model for one sky state (sunZenith radians);
  // bin 1 has its own c and d.
  const z = +sunZenith;
  const tables = skyTables();
  const base = 20 * skySearchRight(tables.perez_clearness_edges, epsilon);
  const x = (p, k) => tables.perez_coefficients[base + 4 * p + k];
  const out = [0, 1, 2, 3, 4].map((p) => x(p, 0) + x(p, 1) * z + delta * (x(p, 2) + x(p, 3) * z));
  if (epsilon < tables.perez_clearness_edges[0]) {
    out[2] = Math.exp(Math.pow(delta * (x(2, 0) + x(2, 1) * z), x(2, 2))) - x(2, 3);
    out[3] = -Math.exp(delta * (x(3, 0) + x(3, 1) * z)) + x(3, 2) + delta * x(3, 3);
  }
  return out;
}

function skyPerezLuminanceAt(dx, dy, dz, s, c) {
  // perez_relative_luminance of one direction (s the unit sun): lv = (1 + a exp(b / cos zeta))
  // (1 + c exp(d gamma) + e cos^2 gamma) (Perez et al. 1993, Eq. 1); zero below the horizon.
  const cosZeta = dz;
  if (!(cosZeta >= 0.0)) return 0.0;
  const cosGamma = skyClip(dx * s[0] + dy * s[1] + dz * s[2], -1.0, 1.0);
  const gamma = Math.acos(cosGamma);
  const gradation = 1.0 + c[0] * Math.exp(c[1] / Math.max(cosZeta, 0.01));  // 0.01: finite at the horizon
  const indicatrix = 1.0 + c[2] * Math.exp(c[3] * gamma) + c[4] * (cosGamma * cosGamma);
  return Math.max(gradation * indicatrix, 0.0);
}

function perezRelativeLuminance(direction, sun, coefficients) {
  return skyPerezLuminanceAt(direction[0], direction[1], direction[2], skyUnit(sun), coefficients);
}

const skyQuadratureCache = {grid: null};  // the 90 x 180 grid, built once

function hemisphereQuadrature(rings = 90, segments = 180) {
  // _hemisphere_quadrature: {directions (rings * segments * 3), solid} midpoints and solid angles of a
  // (zenith x azimuth) grid over the upper hemisphere (zenith edges as numpy's linspace).
  if (rings === 90 && segments === 180 && skyQuadratureCache.grid) return skyQuadratureCache.grid;
  const step = (Math.PI / 2) / rings;
  const edges = new Float64Array(rings + 1);
  for (let i = 0; i < rings; i++) edges[i] = i * step;
  edges[rings] = Math.PI / 2;
  const directions = new Float64Array(rings * segments * 3), solid = new Float64Array(rings * segments);
  const width = 2 * Math.PI / segments;
  for (let i = 0; i < rings; i++) {
    const zeta = (edges[i] + edges[i + 1]) / 2;
    const ring = Math.cos(edges[i]) - Math.cos(edges[i + 1]);
    for (let j = 0; j < segments; j++) {
      const phi = (j + 0.5) * 2 * Math.PI / segments, k = i * segments + j;
      directions[3 * k] = Math.sin(zeta) * Math.sin(phi);
      directions[3 * k + 1] = Math.sin(zeta) * Math.cos(phi);
      directions[3 * k + 2] = Math.cos(zeta);
      solid[k] = ring * width;
    }
  }
  const out = {directions, solid};
  if (rings === 90 && segments === 180) skyQuadratureCache.grid = out;
  return out;
}

function skyPerezState(sun, directNormal, diffuseHorizontal, dayOfYear) {
  // perez_radiance's sky: coefficients for the sun (the sky state with the zenith held at 87 degrees, the
  // coefficients at the true zenith, as the Python) and the scale making integral_H L cos(zeta) dw equal DHI.
  const s = skyUnit(sun);
  const zenith = Math.acos(skyClip(s[2], -1.0, 1.0));
  const [epsilon, delta] = perezSkyState(Math.min(zenith, 87.0 * SKY_DEG2RAD), directNormal, diffuseHorizontal,
                                         dayOfYear);
  const coefficients = perezCoefficients(zenith, epsilon, delta);
  const {directions, solid} = hemisphereQuadrature();
  let horizontal = 0.0;
  for (let k = 0; k < solid.length; k++) {
    const dz = directions[3 * k + 2];
    horizontal += skyPerezLuminanceAt(directions[3 * k], directions[3 * k + 1], dz, s, coefficients) * dz * solid[k];
  }
  const scale = horizontal > 0 ? +diffuseHorizontal / horizontal : 0.0;
  return {sun: s, coefficients, scale};
}

function perezRadiance(direction, sun, directNormal, diffuseHorizontal, dayOfYear = 172) {
  // perez_radiance of one direction: grey [v, v, v] W/(m^2 sr), the Perez all-weather sky scaled to DHI.
  const state = skyPerezState(sun, directNormal, diffuseHorizontal, dayOfYear);
  const v = skyPerezLuminanceAt(direction[0], direction[1], direction[2], state.sun, state.coefficients) * state.scale;
  return [v, v, v];
}

function patchRadiance(samples, model, sunEnu, params = {}) {
  // patch_radiance: Float64Array(N * 3), the mean radiance of each patch over its S samples (Bosch, Besuievsky
  // & Martin, Sec. 5, Eq. 1's Lhat_j). samples: patch_samples(patches, 3) flattened (N * S * 3);
  // params {turbidity = 3, radiance = 1, directNormal = 0, diffuseHorizontal = 0, dayOfYear = 172,
  // samplesPerPatch = 9}.
  const turbidity = params.turbidity ?? 3.0, radiance = params.radiance ?? 1.0;
  const dni = params.directNormal ?? 0.0, dhi = params.diffuseHorizontal ?? 0.0, day = params.dayOfYear ?? 172;
  const perPatch = params.samplesPerPatch ?? 9;
  const count = Math.floor(samples.length / (3 * perPatch));
  const out = new Float64Array(3 * count);
  const value = [0.0, 0.0, 0.0];
  let sample;
  if (model === "perez") {
    const state = skyPerezState(sunEnu, dni, dhi, day);
    sample = (dx, dy, dz) => {
      value[0] = value[1] = value[2] = skyPerezLuminanceAt(dx, dy, dz, state.sun, state.coefficients) * state.scale;
    };
  } else if (model === "preetham") {
    const state = skyPreethamState(sunEnu, turbidity);
    sample = state ? (dx, dy, dz) => skyPreethamAt(state, dx, dy, dz, value, 0)
      : () => { value[0] = value[1] = value[2] = 0.0; };
  } else if (model === "overcast") {
    const s = skyUnit(sunEnu);
    const zenith = (8.6 * Math.max(s[2], 0.0) + 0.123) * 1000.0 / LUMINOUS_EFFICACY;
    sample = (dx, dy, dz) => { value[0] = value[1] = value[2] = zenith * (1 + 2 * Math.max(dz, 0.0)) / 3.0; };
  } else if (model === "uniform") {
    sample = () => { value[0] = value[1] = value[2] = +radiance; };
  } else {
    throw new Error(`unknown sky model ${JSON.stringify(model)} (preetham, perez, overcast, uniform)`);
  }
  for (let n = 0; n < count; n++) {
    let r = 0.0, g = 0.0, b = 0.0;
    for (let k = 0; k < perPatch; k++) {
      const o = 3 * (n * perPatch + k);
      sample(samples[o], samples[o + 1], samples[o + 2]);
      r += value[0]; g += value[1]; b += value[2];
    }
    out[3 * n] = r / perPatch; out[3 * n + 1] = g / perPatch; out[3 * n + 2] = b / perPatch;
  }
  return out;
}

// ---------------------------------------------------------------------------
// kernels/luminous_efficacy.py: Perez, Ineichen, Seals, Michalsky & Stewart 1990, as gendaymtx -O0

const CLEARNESS_RANGE = [1.0, 11.9];
const BRIGHTNESS_RANGE = [0.01, 0.6];
const ZENITH_RANGE_DEG = [3.0, 90.0];
const DEFAULT_DEW_POINT = 11.0;  // degC, gendaymtx's default
function eccentricity(dayOfYear) {
  // (R0 / R)^2, Spencer 1971 (the series gendaymtx uses); dayOfYear 1 = 1 January.
  const angle = (skyFinite(dayOfYear, 1.0) - 1.0) * (2.0 * Math.PI / 365.0);
  return (1.00011 + 0.034221 * Math.cos(angle) + 0.00128 * Math.sin(angle)
          + 0.000719 * Math.cos(2.0 * angle) + 0.000077 * Math.sin(2.0 * angle));
}

function efficacyAirMass(sunZenithDeg) {
  // luminous_efficacy.air_mass: Kasten (1966), zenith (degrees) held in 0..90.
  const zenith = skyClip(skyFinite(sunZenithDeg, 90.0), 0.0, 90.0);
  return 1.0 / (Math.cos(zenith * SKY_DEG2RAD) + 0.15 * Math.pow(93.885 - zenith, -1.253));
}

function precipitableWater(dewPointC) {
  // W (cm) from the surface dew point, eqn 3.
  return Math.exp(0.07 * skyFinite(dewPointC, DEFAULT_DEW_POINT) - 0.075);
}

function efficacySkyState(directNormal, diffuseHorizontal, sunZenithDeg, dayOfYear) {
  // luminous_efficacy.sky_state: [epsilon, Delta] held in CLEARNESS_RANGE and BRIGHTNESS_RANGE (eqns 1, 2).
  const dni = Math.max(skyFinite(directNormal, 0.0), 0.0);
  const dhi = Math.max(skyFinite(diffuseHorizontal, 0.0), 0.0);
  const zenithDeg = skyClip(skyFinite(sunZenithDeg, 90.0), ZENITH_RANGE_DEG[0], ZENITH_RANGE_DEG[1]);
  const z3 = 1.041 * Math.pow(zenithDeg * SKY_DEG2RAD, 3);
  const ratio = dhi > 0.0 ? (dhi + dni) / dhi : (dni > 0.0 ? CLEARNESS_RANGE[1] : 1.0);
  const epsilon = skyClip((ratio + z3) / (1.0 + z3), CLEARNESS_RANGE[0], CLEARNESS_RANGE[1]);
  const delta = dhi * efficacyAirMass(zenithDeg) / (SOLAR_CONSTANT * eccentricity(dayOfYear));
  return [epsilon, skyClip(delta, BRIGHTNESS_RANGE[0], BRIGHTNESS_RANGE[1])];
}

function perezEfficacy(directNormal, diffuseHorizontal, sunZenithDeg, dayOfYear, dewPointC = DEFAULT_DEW_POINT) {
  // perez_efficacy: [K_beam, K_diffuse] lm/W of one hour, eqns 7 and 8 as gendaymtx -O0.
  const [epsilon, delta] = efficacySkyState(directNormal, diffuseHorizontal, sunZenithDeg, dayOfYear);
  const zenith = skyClip(skyFinite(sunZenithDeg, 90.0), ZENITH_RANGE_DEG[0], ZENITH_RANGE_DEG[1]) * SKY_DEG2RAD;
  const water = precipitableWater(dewPointC);
  const tables = skyTables();
  const which = skySearchRight(tables.efficacy_clearness_edges, epsilon);
  let [a, b, c, d] = tables.efficacy_diffuse[which];
  const kDiffuse = a + b * water + c * Math.cos(zenith) + d * Math.log(delta);
  [a, b, c, d] = tables.efficacy_direct[which];
  const kBeam = Math.max(a + b * water + c * Math.exp(5.73 * zenith - 5.0) + d * delta, 0.0);
  return [kBeam, kDiffuse];
}

// ---------------------------------------------------------------------------
// Daylight relighting helpers (kernels/daylight_relight.py)

function visibleFactors(efficacy, directNormal, diffuseHorizontal, sunEnu, day) {
  // visible_factors: [beam, diffuse] from solar to visible-equivalent W/m^2: the Perez 1990 efficacies over
  // 179 lm/W (efficacy "perez", gendaymtx -O0), or [1, 1] ("179", gendaymtx -O1).
  if (efficacy === "179") return [1.0, 1.0];
  const zenith = Math.acos(skyClip(sunEnu[2] / skyNorm(sunEnu), -1.0, 1.0)) * SKY_RAD2DEG;
  const [beam, diffuse] = perezEfficacy(directNormal, diffuseHorizontal, zenith, day);
  return [beam / LUMINOUS_EFFICACY, diffuse / LUMINOUS_EFFICACY];
}

function sunNormal(sky, sunEnu, params = {}) {
  // sun_normal: [r, g, b] direct normal irradiance of the sun (visible-equivalent W/m^2), or null when the
  // model has no sun (overcast, uniform) or it is below the horizon (sunEnu: unit ENU).
  // params {turbidity = 3, directNormal = 0, diffuseHorizontal = 0, dayOfYear = 172, efficacy = "perez"}.
  if ((sky !== "preetham" && sky !== "perez") || sunEnu[2] <= 0) return null;
  const day = params.dayOfYear ?? 172;
  if (sky === "preetham") return sunNormalIrradiance(sunEnu, params.turbidity ?? 3.0, day);
  const dni = params.directNormal ?? 0.0;
  const [beam] = visibleFactors(params.efficacy ?? "perez", dni, params.diffuseHorizontal ?? 0.0, sunEnu, day);
  const value = +dni * beam;
  return [value, value, value];
}

function skyWeights(samples, solidAngles, model, sunLayout, params = {}) {
  // sky_weights: Float64Array(N * 3) Lhat_j * dw_j (W/m^2 per patch): patchRadiance times the patch solid
  // angles (solidAngles: N, patch_solid_angles), the Perez sky times its diffuse visible factor
  // (params.efficacy "perez" or "179"). The Python rounds the result to float32; this stays float64.
  const values = patchRadiance(samples, model, sunLayout, params);
  const factor = model === "perez"
    ? visibleFactors(params.efficacy ?? "perez", params.directNormal ?? 0.0, params.diffuseHorizontal ?? 0.0,
                     sunLayout, params.dayOfYear ?? 172)[1]
    : 1.0;
  for (let n = 0; n < values.length / 3; n++) {
    for (let c = 0; c < 3; c++) {
      values[3 * n + c] = (model === "perez" ? values[3 * n + c] * factor : values[3 * n + c]) * solidAngles[n];
    }
  }
  return values;
}

const SUN_PATCHES = 4;  // gendaymtx: the sun's light spread over the 4 nearest patches, weights 1 / (1.002 - cos)

function horizontalCosines(samples, count) {
  // horizontal_cosines: Float64Array(N), each patch's mean of max(0, z) over its samples (S = length / 3N).
  const perPatch = samples.length / (3 * count);
  const out = new Float64Array(count);
  for (let n = 0; n < count; n++) {
    let sum = 0.0;
    for (let k = 0; k < perPatch; k++) sum += Math.max(samples[3 * (n * perPatch + k) + 2], 0.0);
    out[n] = sum / perPatch;
  }
  return out;
}

function sunPatchWeights(patchDirections, sunEnu, normalIrradiance) {
  // sun_patch_weights: Float64Array(N * 3), the sun's normal irradiance spread over the SUN_PATCHES patches
  // whose centres (patchDirections, N * 3, patch_directions) are nearest it, weights 1 / (1.002 - cos) as
  // gendaymtx; zeros below the horizon. Ties in cos go to the lower patch index (a stable sort of -cos, as
  // numpy's argsort(kind="stable")); numpy's default argsort leaves the order of ties unspecified, so the
  // Python may pick other, equally near patches when the sun sits on a symmetry of the layout (e.g. at the
  // zenith). The Python rounds to float32 (and the irradiance to float32 first); this stays float64.
  const count = Math.floor(patchDirections.length / 3);
  const out = new Float64Array(3 * count);
  if (sunEnu[2] <= 0) return out;
  const s = skyUnit(sunEnu);
  const nearest = [], cosines = [];
  for (let n = 0; n < count; n++) {
    const cos = patchDirections[3 * n] * s[0] + patchDirections[3 * n + 1] * s[1] + patchDirections[3 * n + 2] * s[2];
    let at = nearest.length;
    while (at > 0 && cos > cosines[at - 1]) at--;  // strictly nearer: earlier indices win ties
    if (at < SUN_PATCHES) {
      nearest.splice(at, 0, n);
      cosines.splice(at, 0, cos);
      if (nearest.length > SUN_PATCHES) { nearest.pop(); cosines.pop(); }
    }
  }
  const weights = cosines.map((cos) => 1.0 / (1.002 - cos));
  const total = weights.reduce((a, b) => a + b, 0.0);
  nearest.forEach((n, k) => {
    for (let c = 0; c < 3; c++) out[3 * n + c] = (weights[k] / total) * normalIrradiance[c];
  });
  return out;
}

function groundRadiance(cosines, weights, sunEnu, normalIrradiance, reflectance) {
  // ground_radiance: [r, g, b] radiance of the ground outside the model, rho_g (sky + sun horizontal
  // irradiance) / pi; cosines from horizontalCosines, weights (N * 3) from skyWeights, normalIrradiance
  // [r, g, b] or null.
  // The Python rounds to float32; this stays float64.
  const horizontal = [0.0, 0.0, 0.0];
  for (let n = 0; n < cosines.length; n++) {
    for (let c = 0; c < 3; c++) horizontal[c] += cosines[n] * weights[3 * n + c];
  }
  if (normalIrradiance != null && sunEnu[2] > 0) {
    const norm = skyNorm(sunEnu);
    for (let c = 0; c < 3; c++) horizontal[c] = horizontal[c] + normalIrradiance[c] * sunEnu[2] / norm;
  }
  return horizontal.map((h) => reflectance * h / Math.PI);
}

if (typeof module !== "undefined") {
  module.exports = {
    setSkyTables, dayOfYear, julianDay, refraction, horizontalPosition, sunEnu, sunPosition,
    preethamRadiance, overcastRadiance, airMass, sunNormalIrradiance, perezSkyState, perezCoefficients,
    perezRelativeLuminance, hemisphereQuadrature, perezRadiance, patchRadiance,
    eccentricity, efficacyAirMass, precipitableWater, efficacySkyState, perezEfficacy,
    visibleFactors, sunNormal, skyWeights, horizontalCosines, sunPatchWeights, groundRadiance,
    LUMINOUS_EFFICACY, EXTRATERRESTRIAL_ILLUMINANCE, SOLAR_CONSTANT, SUN_PATCHES,
  };
}
