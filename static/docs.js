// /docs: start Swagger UI (served by the app, no CDN) on the app's OpenAPI spec. An ES module like the others; the
// bundle before it is a classic deferred script, which runs first (deferred scripts and modules run in page order).

document.addEventListener("DOMContentLoaded", () => {
  window.ui = window.SwaggerUIBundle({
    url: "/openapi.json",
    dom_id: "#swagger-ui",
    deepLinking: true,
    presets: [window.SwaggerUIBundle.presets.apis],
    layout: "BaseLayout",
  });
});
