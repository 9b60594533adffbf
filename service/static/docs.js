// Swagger UI on the served document; assets from /static/swagger-ui (no CDN).
"use strict";
window.ui = SwaggerUIBundle({url: "/openapi.json", dom_id: "#swagger-ui", deepLinking: true});
