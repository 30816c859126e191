// The dashboard's refresh script, served at /dashboard.js (the pages'
// Content-Security-Policy allows scripts from 'self' only, none inline).
//
// Every element with `data-src` and `data-every` reloads its content from
// `data-src` while the content says `data-running="true"`; a live part with
// `data-figures` also reloads that element when the job counts change (at
// most every `data-min-interval` ms while running, at once when it stops).
"use strict";
(function () {
  function get(url) {
    return fetch(url, { credentials: "same-origin", cache: "no-store" }).then(function (r) {
      if (r.status === 401) { window.location.reload(); return null; }
      if (!r.ok) { return null; }
      return r.text();
    }, function () { return null; });
  }
  function figures(el, key, now) {
    var last = parseInt(el.getAttribute("data-loaded-at") || "0", 10);
    var min = parseInt(el.getAttribute("data-min-interval") || "15000", 10);
    if (!now && Date.now() - last < min) { return; }
    el.setAttribute("data-loaded-at", String(Date.now()));
    get(el.getAttribute("data-src")).then(function (html) {
      if (html === null) { return; }
      el.innerHTML = html;
      el.setAttribute("data-key", key);
    });
  }
  function watch(el) {
    var every = parseInt(el.getAttribute("data-every"), 10);
    if (!(every >= 500)) { return; }
    var fig = el.getAttribute("data-figures");
    function tick() {
      get(el.getAttribute("data-src")).then(function (html) {
        var again = true;
        if (html !== null) {
          el.innerHTML = html;
          var m = el.querySelector("[data-running]");
          again = !!m && m.getAttribute("data-running") === "true";
          var key = m ? m.getAttribute("data-key") : "";
          var f = fig ? document.getElementById(fig) : null;
          if (f && key && f.getAttribute("data-key") !== key) { figures(f, key, !again); }
        }
        if (again) { window.setTimeout(tick, html === null ? every * 3 : every); }
      });
    }
    window.setTimeout(tick, every);
  }
  function start() {
    var figs = document.querySelectorAll("[data-min-interval]");
    for (var i = 0; i < figs.length; i++) { figs[i].setAttribute("data-loaded-at", String(Date.now())); }
    var els = document.querySelectorAll(".live[data-src]");
    for (var j = 0; j < els.length; j++) { watch(els[j]); }
  }
  if (document.readyState === "loading") { document.addEventListener("DOMContentLoaded", start); } else { start(); }
})();
