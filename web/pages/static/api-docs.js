// Starts Swagger UI (/docs) or ReDoc (/redoc) on this server's own copy of their files:
// an external script, since the pages' Content-Security-Policy runs no inline one.
"use strict";
(function () {
  const swagger = document.getElementById("swagger-ui");
  if (swagger && window.SwaggerUIBundle) {
    window.ui = window.SwaggerUIBundle({
      url: swagger.dataset.openapi,
      dom_id: "#swagger-ui",
      layout: "BaseLayout",
      deepLinking: true,
      showExtensions: true,
      showCommonExtensions: true,
      validatorUrl: null,  // the public validator is another site: the policy blocks it
      presets: [window.SwaggerUIBundle.presets.apis, window.SwaggerUIBundle.SwaggerUIStandalonePreset],
    });
  }
  const redoc = document.getElementById("redoc");
  if (redoc && window.Redoc) {
    // ReDoc's search runs in a worker made from a blob: URL, which the policy refuses:
    // without it the page reads the same (the browser's find works on it).
    window.Redoc.init(redoc.dataset.openapi, { disableSearch: true }, redoc);
  }
}());
