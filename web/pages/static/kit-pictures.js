// armtrack phone kit: the pictures (inline SVG, drawn, no files): a figure in a pose with
// the phone on its segment, and an arrow for the movement. Built with DOM calls only.
"use strict";

const KitPictures = (() => {
  const NS = "http://www.w3.org/2000/svg";
  const INK = "#1d2733", ARM = "#1f6fb2", PHONE = "#e67e22", ARROW = "#1e8a4c";

  function node(name, attrs, ...children) {
    const n = document.createElementNS(NS, name);
    for (const [k, v] of Object.entries(attrs || {})) n.setAttribute(k, String(v));
    for (const c of children) n.append(c);
    return n;
  }
  const rad = (d) => d * Math.PI / 180;
  const line = (a, b, color, width) => node("line", { x1: a[0], y1: a[1], x2: b[0], y2: b[1],
    stroke: color, "stroke-width": width, "stroke-linecap": "round" });

  function phoneOn(a, b) {
    const mx = (a[0] + b[0]) / 2, my = (a[1] + b[1]) / 2;
    const angle = Math.atan2(b[1] - a[1], b[0] - a[0]) * 180 / Math.PI;
    return node("rect", { x: mx - 13, y: my - 7, width: 26, height: 14, rx: 3, fill: PHONE,
      stroke: INK, "stroke-width": 1.5, transform: `rotate(${angle} ${mx} ${my})` });
  }

  function arc(cx, cy, r, fromDeg, toDeg) {
    // an arrow along a circle, angles measured from straight down, counter-clockwise on screen
    const p = (d) => [cx + r * Math.sin(rad(d)), cy + r * Math.cos(rad(d))];
    const [x0, y0] = p(fromDeg), [x1, y1] = p(toDeg);
    const large = Math.abs(toDeg - fromDeg) > 180 ? 1 : 0;
    const sweep = toDeg > fromDeg ? 0 : 1;
    const head = p(toDeg), before = p(toDeg - Math.sign(toDeg - fromDeg) * 12);
    const dx = head[0] - before[0], dy = head[1] - before[1], len = Math.hypot(dx, dy) || 1;
    const ux = dx / len, uy = dy / len;
    return node("g", {},
      node("path", { d: `M ${x0} ${y0} A ${r} ${r} 0 ${large} ${sweep} ${x1} ${y1}`,
        fill: "none", stroke: ARROW, "stroke-width": 4, "stroke-dasharray": "7 5" }),
      node("path", { d: `M ${x1 + ux * 8} ${y1 + uy * 8} L ${x1 - uy * 7} ${y1 + ux * 7} L ${x1 + uy * 7} ${y1 - ux * 7} Z`,
        fill: ARROW }));
  }

  /**
   * A figure: view "front" (arm moves in the frontal plane: `shoulder` is abduction) or
   * "side" (facing right: `shoulder` is flexion); `elbow` flexion [deg]; the phone on
   * `phone` ("forearm", "upper_arm" or none); `arrow` [from, to] degrees of the moving
   * segment's swing, about the shoulder (or the elbow when `arrowAt` is "elbow"). `side`:
   * the patient's arm, drawn as in a mirror (the right arm on the right of the picture);
   * "left" is the same figure mirrored.
   */
  function figure({ view = "front", shoulder = 0, elbow = 0, phone = null, arrow = null,
                    arrowAt = "shoulder", twist = false, label = "", side = "right" } = {}) {
    const picture = node("svg", { viewBox: "0 0 200 210", width: "100%", height: "100%",
      role: "img", "aria-label": label, "data-side": side === "left" ? "left" : "right" });
    const svg = node("g", side === "left" ? { transform: "translate(200 0) scale(-1 1)" } : {});
    picture.append(svg);
    const cx = view === "front" ? 90 : 95;
    const S = view === "front" ? [cx + 24, 58] : [cx, 58];
    svg.append(node("circle", { cx, cy: 28, r: 15, fill: "none", stroke: INK, "stroke-width": 4 }));
    svg.append(line([cx, 44], [cx, 125], INK, 5));
    svg.append(line([cx, 125], [cx - 14, 195], INK, 5), line([cx, 125], [cx + 14, 195], INK, 5));
    if (view === "front") {
      svg.append(line([cx - 24, 58], [cx + 24, 58], INK, 5));
      svg.append(line([cx - 24, 58], [cx - 30, 135], INK, 5));
    }
    const U = 48, F = 44;
    const dir = (d) => view === "front" ? [Math.sin(rad(d)), Math.cos(rad(d))]
      : [Math.sin(rad(d)), Math.cos(rad(d))];
    const u = dir(shoulder), E = [S[0] + U * u[0], S[1] + U * u[1]];
    const f = dir(shoulder + elbow), W = [E[0] + F * f[0], E[1] + F * f[1]];
    if (arrow) {
      const at = arrowAt === "elbow" ? E : S, r = arrowAt === "elbow" ? F + 10 : U + F + 10;
      const base = arrowAt === "elbow" ? shoulder : 0;
      svg.append(arc(at[0], at[1], r, base + arrow[0], base + arrow[1]));
    }
    svg.append(line(S, E, ARM, 8), line(E, W, ARM, 7));
    svg.append(node("circle", { cx: W[0], cy: W[1], r: 6, fill: ARM }));
    if (twist) {  // a turn of the forearm about its own axis
      const m = [(E[0] + W[0]) / 2, (E[1] + W[1]) / 2];
      svg.append(node("ellipse", { cx: m[0], cy: m[1], rx: 9, ry: 22, fill: "none",
        stroke: ARROW, "stroke-width": 4, "stroke-dasharray": "6 4",
        transform: `rotate(${-Math.atan2(f[0], f[1]) * 180 / Math.PI} ${m[0]} ${m[1]})` }));
    }
    if (phone === "forearm") svg.append(phoneOn(W, E));
    if (phone === "upper_arm") svg.append(phoneOn(E, S));
    return picture;
  }

  /** The picture of a named step or exercise for a phone on `sensor`, on the patient's
   * `side` arm ("right" or "left"). */
  function named(name, sensor, side = "right") {
    const phone = sensor;
    const drawn = (spec) => figure({ ...spec, side });
    switch (name) {
      case "segment:forearm": return drawn({ view: "front", phone: "forearm", label: "phone on the forearm" });
      case "segment:upper_arm": return drawn({ view: "front", phone: "upper_arm", label: "phone on the upper arm" });
      case "npose": return drawn({ view: "front", phone, label: "arm hanging, thumb forward" });
      case "tpose": return drawn({ view: "front", shoulder: 90, phone, label: "arm straight out to the side" });
      case "elbow_flexion": return drawn({ view: "side", elbow: 120, phone, arrow: [0, 120], arrowAt: "elbow", label: "bend the elbow" });
      case "pronation": return drawn({ view: "side", elbow: 90, phone, twist: true, label: "turn the palm down and up" });
      case "shoulder_flexion": return drawn({ view: "side", shoulder: 150, phone, arrow: [0, 150], label: "raise the arm forward" });
      case "shoulder_abduction": return drawn({ view: "front", shoulder: 90, phone, arrow: [0, 90], label: "raise the arm to the side" });
      default: return drawn({ view: "front", phone, label: name });
    }
  }

  return { figure, named };
})();

window.KitPictures = KitPictures;
