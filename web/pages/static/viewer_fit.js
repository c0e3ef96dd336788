// The 3D view keeps viser's desktop layout in a narrow box (a phone): below 576 px viser
// switches to its phone layout, whose control panel opens as a sheet over the scene and
// ignores the server's "start minimised". So a box narrower than FIT_WIDTH renders the
// view FIT_WIDTH px wide and scales it down to the box (pointer input follows the scale).
"use strict";

(() => {
  const FIT_WIDTH = 600;
  const box = document.getElementById("viewer");
  if (!box || !window.ResizeObserver) return;
  const fit = () => {
    const frame = document.getElementById("viewer-frame");
    if (!frame) return;
    const width = box.clientWidth, height = box.clientHeight;
    if (!width || width >= FIT_WIDTH) {
      frame.style.width = frame.style.height = frame.style.transform = "";
      return;
    }
    const k = width / FIT_WIDTH;
    frame.style.width = FIT_WIDTH + "px";
    frame.style.height = height / k + "px";
    frame.style.transformOrigin = "0 0";
    frame.style.transform = `scale(${k})`;
  };
  new ResizeObserver(fit).observe(box);
  new MutationObserver(fit).observe(box, { childList: true });
})();
