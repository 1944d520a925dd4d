// usdbake viewer: the daylight controls (date, hour, sky, weather-file hour, exposure, false colour, annual
// overlays) read into the sky parameters daylight.js relights with, and the false-colour legend.
"use strict";

function localTime(date, hour) {
  // ms of the local standard clock as if it were UTC (what sky.js's sunPosition takes)
  const [y, m, d] = date.split("-").map(Number);
  return Date.UTC(y, m - 1, d) + Math.round(hour * 3600e3);
}

function formatTime(ms) {
  const t = new Date(ms);
  const two = x => String(x).padStart(2, "0");
  return `${t.getUTCFullYear()}-${two(t.getUTCMonth() + 1)}-${two(t.getUTCDate())} ${two(t.getUTCHours())}:${two(t.getUTCMinutes())}`;
}

function readControls() {
  const value = id => document.getElementById(id).value;
  const checked = id => document.getElementById(id).checked;
  return {date: value("date"), hour: parseFloat(value("hour")), model: value("sky"), turbidity: parseFloat(value("turbidity")),
          directNormal: parseFloat(value("dni")), diffuseHorizontal: parseFloat(value("dhi")), sun: checked("sun"),
          useWeather: checked("useWeather"), weatherHour: parseInt(value("weatherHour"), 10),
          exposure: Math.pow(2, parseFloat(value("exposure"))), falseColour: checked("falseColour"), overlay: value("overlay"),
          luxLow: parseFloat(value("luxLow")), luxHigh: parseFloat(value("luxHigh"))};
}

function skyFor(controls, weather) {
  // (local time ms, sky parameters) of the controls; a weather-file hour sets the time and the Perez sky.
  const sky = {model: controls.model, turbidity: controls.turbidity, radiance: 1000, directNormal: controls.directNormal,
               diffuseHorizontal: controls.diffuseHorizontal, efficacy: "perez", sun: controls.sun};
  if (controls.useWeather && weather) {
    const row = Math.min(Math.max(controls.weatherHour, 0), weather.times.length - 1);
    return {when: weather.times[row], sky: {...sky, model: "perez", directNormal: weather.direct[row], diffuseHorizontal: weather.diffuse[row]}, row};
  }
  return {when: localTime(controls.date, controls.hour), sky, row: -1};
}

// The annual overlays the server may send (stages/serve.py ANNUAL_PRIMVARS): label and legend range.
const OVERLAYS = {
  daylightAutonomy: ["daylight autonomy (share of occupied hours)", 0, 1],
  usefulDaylightWithin: ["UDI within the band (share)", 0, 1],
  usefulDaylightBelow: ["UDI below the band (share)", 0, 1],
  usefulDaylightAbove: ["UDI above the band (share)", 0, 1],
  daylightFactor: ["daylight factor (%)", 0, 10],
  annualSunHours: ["sunlit occupied hours", 0, 500],
  meanIlluminance: ["mean illuminance (lux)", 0, 2000],
};

function decodeOverlay(buffer) {
  // formats/daylight_stream.encode_overlay: magic, JSON, zlib (M, F) float32
  const view = new DataView(buffer.buffer, buffer.byteOffset, buffer.byteLength), length = view.getUint32(8, true);
  const summary = JSON.parse(new TextDecoder().decode(buffer.subarray(12, 12 + length)));
  return inflate(buffer.subarray(12 + length)).then(bytes => {
    const values = new Float32Array(bytes.buffer), F = summary.faces;
    return {summary, metrics: Object.fromEntries(summary.metrics.map((name, k) => [name, values.subarray(k * F, (k + 1) * F)]))};
  });
}

function drawLegend(low, high, linear = false) {
  const canvas = document.getElementById("legend"), context = canvas.getContext("2d");
  const w = canvas.width, h = canvas.height;
  context.clearRect(0, 0, w, h);
  for (let x = 0; x < w; x++) {
    const t = x / (w - 1), c = [1.5 - Math.abs(4 * t - 3), 1.5 - Math.abs(4 * t - 2), 1.5 - Math.abs(4 * t - 1)]
      .map(v => Math.round(255 * Math.min(Math.max(v, 0), 1)));
    context.fillStyle = `rgb(${c[0]},${c[1]},${c[2]})`;
    context.fillRect(x, 0, 1, h - 14);
  }
  context.fillStyle = "#ddd";
  context.font = "11px sans-serif";
  const ticks = 4;
  for (let i = 0; i <= ticks; i++) {
    const lux = linear ? low + (high - low) * i / ticks : low * Math.pow(high / low, i / ticks);
    context.textAlign = i === 0 ? "left" : i === ticks ? "right" : "center";
    context.fillText(lux >= 100 ? lux.toFixed(0) : lux.toPrecision(2), i * (w - 1) / ticks, h - 2);
  }
}
