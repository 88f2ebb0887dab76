{# The grade page's only script: its self-check (see _selfcheck.js). #}
{% from "_selfcheck.js" import on_load %}
(function () {
  "use strict";
  var errors = 0, csp = 0;
  window.addEventListener("error", function () { errors++; }, true);
  window.addEventListener("securitypolicyviolation", function () { csp++; });
{{ on_load(false) }}
})();
