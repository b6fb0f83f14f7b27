// The 3D deviation view: the deviation cloud (decimated by the console) drawn as coloured
// points with a depth buffer on a 2D canvas; drag rotates, the wheel zooms, a click picks the
// nearest visible point and reads its coordinates and deviation. Regions of the table are
// marked where they lie.
(function () {
  "use strict";
  var canvas = document.getElementById("view");
  if (!canvas) return;
  var status = document.getElementById("view-status");
  var pick = document.getElementById("pick");
  var tol = parseFloat(canvas.getAttribute("data-tolerance")) || 1;
  var ctx = canvas.getContext("2d");
  var W = canvas.width, H = canvas.height;
  var n = 0, pts = null, colours = null, sx = null, sy = null, sz = null;
  var centre = [0, 0, 0], radius = 1;
  var yaw = -0.6, pitch = 0.9, zoom = 1;
  var marker = null;
  var image = ctx.createImageData(W, H);
  var pix = new Uint32Array(image.data.buffer);
  var depth = new Float32Array(W * H);

  function colour(d) {
    // As the cell's map: green within tolerance, cyan to blue below, yellow to red above.
    if (!isFinite(d)) return [40, 40, 40];
    var t = Math.max(-2, Math.min(2, d / tol));
    if (Math.abs(t) <= 1) { var g = 0.55 + 0.35 * Math.abs(t); return [40 + 60 * Math.abs(t), 255 * g, 60]; }
    var u = Math.abs(t) - 1;
    return t < 0 ? [0, 255 * (1 - u), 255] : [255, 255 * (1 - u), 0];
  }

  function draw() {
    if (!pts) return;
    pix.fill(0xff111111);
    depth.fill(-Infinity);
    var cy = Math.cos(yaw), syw = Math.sin(yaw), cp = Math.cos(pitch), sp = Math.sin(pitch);
    var s = zoom * 0.45 * Math.min(W, H) / radius;
    for (var i = 0; i < n; i++) {
      var x = pts[4 * i] - centre[0], y = pts[4 * i + 1] - centre[1], z = pts[4 * i + 2] - centre[2];
      var x1 = cy * x - syw * y, y1 = syw * x + cy * y;
      var y2 = cp * y1 - sp * z, z2 = sp * y1 + cp * z;
      var px = W / 2 + s * x1, py = H / 2 - s * y2;
      sx[i] = px; sy[i] = py; sz[i] = z2;
      var ix = px | 0, iy = py | 0;
      if (ix < 0 || iy < 0 || ix >= W - 1 || iy >= H - 1) continue;
      var k = iy * W + ix;
      if (z2 > depth[k]) { depth[k] = z2; pix[k] = colours[i]; }
      if (z2 > depth[k + 1]) { depth[k + 1] = z2; pix[k + 1] = colours[i]; }
      if (z2 > depth[k + W]) { depth[k + W] = z2; pix[k + W] = colours[i]; }
      if (z2 > depth[k + W + 1]) { depth[k + W + 1] = z2; pix[k + W + 1] = colours[i]; }
    }
    ctx.putImageData(image, 0, 0);
    if (marker) {
      var m = project(marker, cy, syw, cp, sp, s);
      ctx.strokeStyle = "#fff"; ctx.lineWidth = 2;
      ctx.beginPath(); ctx.arc(m[0], m[1], 14, 0, 2 * Math.PI); ctx.stroke();
    }
  }

  function project(p, cy, syw, cp, sp, s) {
    var x = p[0] - centre[0], y = p[1] - centre[1], z = p[2] - centre[2];
    var x1 = cy * x - syw * y, y1 = syw * x + cy * y;
    var y2 = cp * y1 - sp * z;
    return [W / 2 + s * x1, H / 2 - s * y2];
  }

  function pickAt(mx, my) {
    var best = -1, bestZ = -Infinity, r2 = 36;
    for (var i = 0; i < n; i++) {
      var dx = sx[i] - mx, dy = sy[i] - my;
      if (dx * dx + dy * dy <= r2 && sz[i] > bestZ) { bestZ = sz[i]; best = i; }
    }
    if (best < 0) { pick.textContent = "No point there."; pick.removeAttribute("data-index"); return; }
    var x = pts[4 * best], y = pts[4 * best + 1], z = pts[4 * best + 2], d = pts[4 * best + 3];
    pick.setAttribute("data-index", best);
    pick.setAttribute("data-x", x); pick.setAttribute("data-y", y); pick.setAttribute("data-z", z);
    pick.setAttribute("data-deviation", d);
    pick.textContent = "Point (" + x.toFixed(3) + ", " + y.toFixed(3) + ", " + z.toFixed(3) + ") mm: deviation " +
      (d >= 0 ? "+" : "") + d.toFixed(3) + " mm" + (Math.abs(d) > tol ? " (out of tolerance)" : "");
    marker = [x, y, z];
    draw();
  }

  var dragging = false, moved = false, lx = 0, ly = 0;
  canvas.addEventListener("pointerdown", function (e) { dragging = true; moved = false; lx = e.clientX; ly = e.clientY; });
  window.addEventListener("pointerup", function (e) {
    if (dragging && !moved) {
      var r = canvas.getBoundingClientRect();
      pickAt((e.clientX - r.left) * W / r.width, (e.clientY - r.top) * H / r.height);
    }
    dragging = false;
  });
  canvas.addEventListener("pointermove", function (e) {
    if (!dragging) return;
    var dx = e.clientX - lx, dy = e.clientY - ly;
    if (Math.abs(dx) + Math.abs(dy) > 2) moved = true;
    if (!moved) return;
    yaw += dx * 0.01; pitch = Math.max(-Math.PI, Math.min(Math.PI, pitch + dy * 0.01));
    lx = e.clientX; ly = e.clientY;
    draw();
  });
  canvas.addEventListener("wheel", function (e) {
    e.preventDefault();
    zoom = Math.max(0.2, Math.min(50, zoom * (e.deltaY < 0 ? 1.15 : 1 / 1.15)));
    draw();
  }, { passive: false });
  document.querySelectorAll("tr.region").forEach(function (row) {
    row.addEventListener("click", function () {
      document.querySelectorAll("tr.region.on").forEach(function (r) { r.classList.remove("on"); });
      row.classList.add("on");
      marker = [parseFloat(row.getAttribute("data-x")), parseFloat(row.getAttribute("data-y")), parseFloat(row.getAttribute("data-z"))];
      draw();
    });
  });

  var t0 = performance.now();
  status.textContent = "Loading the deviation cloud…";
  fetch(canvas.getAttribute("data-src"), { credentials: "same-origin" })
    .then(function (r) { if (!r.ok) throw new Error("HTTP " + r.status); return r.arrayBuffer(); })
    .then(function (buf) {
      var head = new DataView(buf);
      n = head.getUint32(0, true);
      var total = head.getUint32(4, true);
      pts = new Float32Array(buf, 8, 4 * n);
      colours = new Uint32Array(n);
      sx = new Float32Array(n); sy = new Float32Array(n); sz = new Float32Array(n);
      var lo = [Infinity, Infinity, Infinity], hi = [-Infinity, -Infinity, -Infinity];
      for (var i = 0; i < n; i++) {
        for (var a = 0; a < 3; a++) { var v = pts[4 * i + a]; if (v < lo[a]) lo[a] = v; if (v > hi[a]) hi[a] = v; }
        var c = colour(pts[4 * i + 3]);
        colours[i] = (255 << 24) | ((c[2] & 255) << 16) | ((c[1] & 255) << 8) | (c[0] & 255);
      }
      centre = [(lo[0] + hi[0]) / 2, (lo[1] + hi[1]) / 2, (lo[2] + hi[2]) / 2];
      radius = Math.max(1e-6, Math.hypot(hi[0] - lo[0], hi[1] - lo[1], hi[2] - lo[2]) / 2);
      draw();
      var ms = performance.now() - t0;
      canvas.setAttribute("data-ready-ms", ms.toFixed(0));
      canvas.setAttribute("data-points", n);
      status.textContent = n + " of " + total + " points shown" + (n < total ? " (decimated)" : "") + "; ready in " + ms.toFixed(0) + " ms.";
    })
    .catch(function (e) { status.textContent = "The deviation cloud cannot be shown: " + e.message; });
})();
