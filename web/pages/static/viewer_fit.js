// The 3D view keeps viser's desktop layout in a narrow box (a phone): below 576 px viser
// switches to its phone layout, whose control panel opens as a sheet over the scene and
// ignores the server's "start minimised". So a box narrower than FIT_WIDTH renders the
// view FIT_WIDTH px wide and scales it down to the box (pointer input follows the scale).
// viewerFitScale(box) says by how much (1: not scaled); the page sends it with its viewer
// request so the server draws the in-scene labels larger, and a "viewer-scale" event on
// the box tells when the scale changed (the page then asks for a view sized anew).
"use strict";

const FIT_WIDTH = 600;

function viewerFitScale(box) {
  const width = box.clientWidth;
  return !width || width >= FIT_WIDTH ? 1 : width / FIT_WIDTH;
}

(() => {
  const box = document.getElementById("viewer");
  if (!box || !window.ResizeObserver) return;
  let last = null;
  const fit = () => {
    const k = viewerFitScale(box);
    if (last !== null && k !== last) box.dispatchEvent(new CustomEvent("viewer-scale", { detail: k }));
    last = k;
    const frame = document.getElementById("viewer-frame");
    if (!frame) return;
    if (k >= 1) {
      frame.style.width = frame.style.height = frame.style.transform = "";
      return;
    }
    frame.style.width = FIT_WIDTH + "px";
    frame.style.height = box.clientHeight / k + "px";
    frame.style.transformOrigin = "0 0";
    frame.style.transform = `scale(${k})`;
  };
  new ResizeObserver(fit).observe(box);
  new MutationObserver(fit).observe(box, { childList: true });
})();
