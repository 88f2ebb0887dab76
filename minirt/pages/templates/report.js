{% from "_selfcheck.js" import on_load %}
(function () {
  "use strict";
  // Self-check for the browser test (and for anyone who opens the console): on load, the body element gets
  // data-images-loaded="N/M", data-errors, data-alerts, data-csp-violations and data-ready.
  var errors = 0, alerts = 0, csp = 0;
  window.addEventListener("error", function () { errors++; }, true);  // capture: failed image loads too
  window.addEventListener("securitypolicyviolation", function () { csp++; });
  window.alert = function () { alerts++; };
  window.confirm = function () { alerts++; return false; };
  window.prompt = function () { alerts++; return null; };
  var consoleError = console.error;
  console.error = function () { errors++; return consoleError.apply(console, arguments); };

  var filter = "all";

  function apply() {
    var q = (document.getElementById("search").value || "").trim().toLowerCase();
    var shown = 0, all = document.querySelectorAll("section.scene");
    for (var i = 0; i < all.length; i++) {
      var s = all[i];
      var verdicts = (s.getAttribute("data-verdicts") || "").split(" ");
      var ok = (filter === "all" || verdicts.indexOf(filter) >= 0) &&
               (q === "" || (s.getAttribute("data-name") || "").indexOf(q) >= 0);
      s.hidden = !ok;
      if (ok) shown++;
    }
    document.getElementById("shown").textContent = shown + " of " + all.length + " shown";
    document.getElementById("none").hidden = shown > 0;
  }

  document.addEventListener("DOMContentLoaded", function () {
    var buttons = document.querySelectorAll("#filters button[data-filter]");
    for (var i = 0; i < buttons.length; i++) {
      buttons[i].addEventListener("click", function (ev) {
        filter = ev.currentTarget.getAttribute("data-filter");
        for (var j = 0; j < buttons.length; j++) buttons[j].classList.toggle("on", buttons[j] === ev.currentTarget);
        apply();
      });
    }
    document.getElementById("search").addEventListener("input", apply);
    document.getElementById("swap-all").addEventListener("change", function (ev) {
      document.body.classList.toggle("show-ref", ev.currentTarget.checked);
    });
    document.getElementById("expand").addEventListener("click", function (ev) {
      var open = ev.currentTarget.textContent === "Expand all", all = document.querySelectorAll("details.backend");
      for (var d = 0; d < all.length; d++) all[d].open = open;
      ev.currentTarget.textContent = open ? "Collapse all" : "Expand all";
    });
    var stacks = document.querySelectorAll(".stack");
    for (var k = 0; k < stacks.length; k++) {
      stacks[k].addEventListener("click", function (ev) { ev.currentTarget.classList.toggle("pinned"); });
      stacks[k].addEventListener("keydown", function (ev) {
        if (ev.key === " " || ev.key === "Enter") { ev.preventDefault(); ev.currentTarget.classList.toggle("pinned"); }
      });
    }
    apply();
  });

{{ on_load(true) }}
})();
