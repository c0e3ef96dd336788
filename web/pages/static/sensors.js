// The live sensor table, shared by the patient page and the live session page.
"use strict";

const SENSOR_LABELS = { upper_arm: "Upper arm", forearm: "Forearm", hand: "Hand",
  trunk: "Trunk (sternum)", clavicle: "Clavicle" };

function sensorTable(live) {
  const rows = live.sensors.map((s) => {
    let state, dot, cls;
    if (s.connected) { state = "Connected"; dot = "on"; cls = "conn-on"; }
    else if (s.socket_open) { state = "No data"; dot = "stale"; cls = "conn-stale"; }
    else { state = "Connection lost"; dot = "off"; cls = "conn-off"; }
    const battery = s.battery === null || s.battery === undefined ? "—"
      : Math.round(s.battery * 100) + " %" + (s.battery < 0.2 ? " (low)" : "");
    return el("tr", { class: cls, dataset: { sensor: s.sensor } },
      el("td", {}, SENSOR_LABELS[s.sensor] || s.sensor),
      el("td", { class: "conn" }, el("span", { class: "dot " + dot }), state),
      el("td", { class: "num rate" }, s.samples_per_s === null || s.samples_per_s === undefined ? "—" : Math.round(s.samples_per_s)),
      el("td", { class: "num" }, fmtPercent(s.lost_fraction)),
      el("td", { class: "num seen" }, fmtAgo(s.seconds_since)),
      el("td", { class: "num" }, battery),
      el("td", { class: "num" }, s.rssi_dbm === null || s.rssi_dbm === undefined ? "—" : s.rssi_dbm + " dBm"));
  });
  return el("table", { id: "sensor-table" },
    el("thead", {}, el("tr", {}, el("th", {}, "Sensor"), el("th", {}, "Connection"),
      el("th", { class: "num" }, "Samples/s"), el("th", { class: "num" }, "Lost"),
      el("th", { class: "num" }, "Last seen"), el("th", { class: "num" }, "Battery"),
      el("th", { class: "num" }, "Signal"))),
    el("tbody", {}, rows));
}

// While the server cannot store what kits send (a full disk, a locked database: the live
// status's ``storage_failing``), the sensors still look connected: this says what is
// happening to the data and who can mend it. Null when storing works.
function storageNote(live) {
  const failing = live.storage_failing;
  if (!failing) return null;
  const since = fmtDate(new Date(failing.since * 1000).toISOString(), { seconds: true });
  return el("div", { id: "storage-failing", class: "card stopped-by-server", role: "alert" },
    el("h3", {}, "What the kit sends is not stored just now"),
    el("p", {}, `Since ${since} the server's database says “${failing.reason}”.`),
    el("p", {}, "The kit keeps its readings and sends them again once the server can store "
      + "them: nothing is lost while it does, so let the patient carry on or pause. "
      + "Tell the clinic's IT: the server needs room on its disk or its database needs attention."));
}
