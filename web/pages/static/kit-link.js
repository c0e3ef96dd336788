// armtrack dashboard: the phone kit's link and QR code, shown once when a kit is added
// on the patient page (docs/extensions/kit-link.md). Its own file: the patient page only
// calls showKitLink(device, box). Texts go in as text; the QR code is an <img> of the
// server's SVG data: URI.
"use strict";

/** Whether `url` names the computer it is opened on (a loopback address, as the server's
 * LOCAL_HOSTS in server/kit/link.py): on the patient's phone that is the phone itself. */
function namesThisComputer(url) {
  const host = new URL(url).hostname;
  return host === "localhost" || host.endsWith(".localhost") || host === "[::1]" || /^127\./.test(host);
}

function showKitLink(device, box) {
  if (!device.kit_url) return;
  const copy = el("button", { class: "secondary", id: "copy-kit-link", onclick: async () => {
    try { await navigator.clipboard.writeText(device.kit_url); copy.textContent = "Copied ✓"; }
    catch (_) { copy.textContent = "Select and copy by hand"; }
  } }, "Copy link");
  const warning = namesThisComputer(device.kit_url)
    ? el("p", { class: "notice", id: "kit-link-local" },
      `This link names this computer (${new URL(device.kit_url).hostname}): a phone cannot open it. ` +
      "To try the phone kit here, open the link in this browser; for patients, ask your IT to " +
      "set ARMTRACK_PUBLIC_URL to the server's https address (docs/phone-kit.md).")
    : device.kit_url_secure ? null : el("p", { class: "notice", id: "kit-link-insecure" },
      "This link is not https: phones give motion sensors only to https pages. Ask your IT to set " +
      "ARMTRACK_PUBLIC_URL to the server's https address (docs/phone-kit.md).");
  box.append(el("div", { class: "kitlink", id: "kit-link" },
    el("div", { class: "kitlink-qr" },
      el("img", { src: device.kit_qr, alt: "QR code of the phone kit's link", id: "kit-qr", width: 200, height: 200 })),
    el("div", { class: "kitlink-steps" },
      el("b", {}, "Or use the patient's phone as the kit"),
      warning,
      el("ol", {},
        el("li", {}, "On the patient's phone, scan this code with the camera (or send them the link)."),
        el("li", {}, "The page opens; tap “Start” and choose where the phone goes: forearm or upper arm."),
        el("li", {}, "Show them how to strap it: outside of the arm, screen out, top toward the joint above."),
        el("li", {}, "Add the page to the home screen (browser menu): it opens without a network too.")),
      el("div", { class: "row", style: "align-items:center;margin-top:6px" },
        el("code", { class: "token grow", id: "kit-url" }, device.kit_url), copy),
      el("p", { class: "muted small" }, "The link holds the kit's token: give it to this patient only. Revoke the kit to stop it."))));
}
