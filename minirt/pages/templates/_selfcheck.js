{# The load half of a page's self-check, for the browser tests (and anyone who opens the console): on load,
   the body element gets data-images-loaded="N/M", data-errors, data-csp-violations, data-ready, and
   data-alerts where the page counts them (count_alerts). The counters are the calling script's. #}
{% macro on_load(count_alerts) %}
  window.addEventListener("load", function () {
    var imgs = document.images, loaded = 0;
    for (var i = 0; i < imgs.length; i++) if (imgs[i].complete && imgs[i].naturalWidth > 0) loaded++;
    var b = document.body;
    b.setAttribute("data-images-loaded", loaded + "/" + imgs.length);
    b.setAttribute("data-errors", String(errors));
{% if count_alerts %}
    b.setAttribute("data-alerts", String(alerts));
{% endif %}
    b.setAttribute("data-csp-violations", String(csp));
    b.setAttribute("data-ready", "1");
  });
{%- endmacro %}
