// Live page: server-sent events from the console; each event refreshes the fragments the
// page shows (cells, a scan's progress) and raises alarms. Reloads a scan's page when the
// scan it waits for is recorded.
(function () {
  "use strict";
  function refresh() {
    document.querySelectorAll("[data-fragment]").forEach(function (el) {
      fetch(el.getAttribute("data-fragment"), { credentials: "same-origin" })
        .then(function (r) { return r.ok ? r.text() : null; })
        .then(function (html) {
          if (html === null) return;
          var t = document.createElement("template");
          t.innerHTML = html.trim();
          var fresh = t.content.firstElementChild;
          if (fresh && el.isConnected) el.replaceWith(fresh);
        });
    });
  }
  var pending = false;
  function soon() {
    if (pending) return;
    pending = true;
    setTimeout(function () { pending = false; refresh(); }, 30);
  }
  var scanBox = document.querySelector("[data-scan]");
  var es = new EventSource("/events");
  es.onmessage = function (m) {
    var e;
    try { e = JSON.parse(m.data); } catch (_) { return; }
    if (e.event === "alarm") {
      var a = document.getElementById("alarm");
      a.textContent = "ALARM " + e.alarm.cell + ": " + e.alarm.message;
      a.hidden = false;
    }
    if (e.event === "fused") {
      var shown = false;
      document.querySelectorAll("img.fused").forEach(function (img) {
        if (img.getAttribute("data-cell") === e.cell && img.getAttribute("data-sensor") === e.sensor) {
          img.src = img.src.split("?")[0] + "?n=" + e.count;
          shown = true;
        }
      });
      if (!shown) soon();
      return;
    }
    if (e.event === "recorded" && scanBox &&
        e.scan.scan_id === scanBox.getAttribute("data-scan") &&
        e.scan.cell === scanBox.getAttribute("data-cell")) {
      location.reload();
      return;
    }
    soon();
  };
})();
