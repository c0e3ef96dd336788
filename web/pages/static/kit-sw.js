// armtrack phone kit's service worker: the kit page opens without a network. Network
// first (so an update arrives at once), the cached copy when offline. Only the kit's own
// files; never the API or the stream (their answers are the patient's data).
"use strict";
const CACHE = "armtrack-kit-v2";
const FILES = ["/kit", "/kit.webmanifest", "/assets/kit.css", "/assets/kit.js",
               "/assets/kit-stream.js", "/assets/kit-pictures.js", "/assets/kit-program.js",
               "/assets/kit-icon.svg"];

self.addEventListener("install", (event) => {
  event.waitUntil(caches.open(CACHE).then((cache) => cache.addAll(FILES)).then(() => self.skipWaiting()));
});
self.addEventListener("activate", (event) => {
  event.waitUntil(caches.keys()
    .then((names) => Promise.all(names.filter((n) => n !== CACHE).map((n) => caches.delete(n))))
    .then(() => self.clients.claim()));
});
self.addEventListener("fetch", (event) => {
  const url = new URL(event.request.url);
  if (event.request.method !== "GET" || url.origin !== location.origin) return;
  const path = url.pathname;
  if (!FILES.includes(path)) return;
  event.respondWith(fetch(event.request).then((answer) => {
    if (answer.ok) {
      const copy = answer.clone();
      caches.open(CACHE).then((cache) => cache.put(path, copy));
    }
    return answer;
  }).catch(() => caches.match(path)));
});
