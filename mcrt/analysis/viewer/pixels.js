/* mcrt study report, the viewer's pixels (see viewer.js): what a panel shows, the error
 * views, drawing, the state on screen, zoom and pan, the pixel readout. */

// ------------------------------------------------------------------ pixels
// What a panel shows: {kind: "ref"} or {kind: "cell", sampler, key} (or null: pending).
Viewer.prototype.target = function (which) {
  if (which === "ref" || (which === "selected" && this.s.ref)) return {kind: "ref"};
  var sampler = which === "selected" ? this.s.sampler : which;
  var key = this.cellKey(sampler, this.s.spp);
  if (!this.data.cells[key]) return null;
  return {kind: "cell", sampler: sampler, key: key};
};

Viewer.prototype.source = function (t) {
  return t.kind === "ref" ? this.arrays.ref : this.arrays[t.key + "/" + this.s.source];
};

// The value of the current error view at pixel i of target t (cell targets only).
Viewer.prototype.errorAt = function (t, i) {
  var view = this.s.view, ref = this.arrays.ref;
  if (view === "flip") return this.arrays[t.key + "/flip"][i];
  if (view === "variance") return this.arrays[t.key + "/variance"][i];
  var img = this.source(t), j = 3 * i;
  var yr = LUM[0] * ref[j] + LUM[1] * ref[j + 1] + LUM[2] * ref[j + 2];
  var d = LUM[0] * img[j] + LUM[1] * img[j + 1] + LUM[2] * img[j + 2] - yr;
  if (view === "signed") return d;
  if (view === "abs") return Math.abs(d);
  return Math.abs(d) / Math.sqrt(yr * yr + REL_EPS);
};

// Colour-bar maximum of an error view: the 99th percentile over every sampler at this
// spp (computed with the report: mcrt/analysis/viewer/data.py), times the user's factor.
Viewer.prototype.scaleMax = function () {
  var view = this.s.view;
  if (view === "flip") return 1;
  var p = (this.data.scales || {})[view + "/" + this.data.spp[this.s.spp] + "/" + this.s.source];
  return (p > 0 ? p : 1) * this.s.errScale;
};

Viewer.prototype.draw = function (canvas, t, x0, y0, w, h) {
  var ctx = canvas.getContext("2d"), img = ctx.createImageData(w, h), px = img.data;
  var rgb = [0, 0, 0], gain = Math.pow(2, this.s.exposure);
  var view = t && t.kind === "cell" ? this.s.view : "image";
  var max = view === "image" ? 1 : this.scaleMax();
  var map = view === "signed" ? "diverging" : view === "flip" ? "magma" : "viridis";
  var src = t ? this.source(t) : null;
  for (var y = 0; y < h; y++) {
    for (var x = 0; x < w; x++) {
      var i = (y0 + y) * this.w + (x0 + x), o = 4 * (y * w + x);
      px[o + 3] = 255;
      if (!t) { px[o] = px[o + 1] = px[o + 2] = 64; continue; }
      if (view === "image") {
        var r = src[3 * i], g = src[3 * i + 1], b = src[3 * i + 2];
        if (!isFinite(r) || !isFinite(g) || !isFinite(b)) {
          px[o] = NONFINITE[0]; px[o + 1] = NONFINITE[1]; px[o + 2] = NONFINITE[2];
        } else {
          px[o] = srgb(r * gain); px[o + 1] = srgb(g * gain); px[o + 2] = srgb(b * gain);
        }
        continue;
      }
      var e = this.errorAt(t, i);
      if (!isFinite(e)) {
        px[o] = NONFINITE[0]; px[o + 1] = NONFINITE[1]; px[o + 2] = NONFINITE[2];
        continue;
      }
      mapColour(map, view === "signed" ? 0.5 + 0.5 * e / max : e / max, rgb);
      px[o] = rgb[0]; px[o + 1] = rgb[1]; px[o + 2] = rgb[2];
    }
  }
  ctx.putImageData(img, 0, 0);
};

// ------------------------------------------------------------------ state -> screen
Viewer.prototype.render = function () {
  var self = this, d = this.data, s = this.s;
  this.pins = {};
  this.panels.forEach(function (p) {
    var shown = s.layout === "grid" ? p.which !== "selected" : p.which === "selected";
    p.box.style.display = shown ? "" : "none";
    if (!shown) return;
    var t = self.target(p.which);
    var name = !t ? d.samplers[p.which === "selected" ? s.sampler : p.which] :
      t.kind === "ref" ? "reference" : d.samplers[t.sampler];
    var cell = t && t.kind === "cell" ? d.cells[t.key] : null;
    p.title.textContent = !t ? name + ": pending" : t.kind === "ref" ?
      "reference (" + d.reference_spp + " spp)" :
      name + " \u00b7 " + cell.spp + " spp \u00b7 " + (s.source === "mean" ?
        "mean of " + d.seeds.length + " seeds" : "seed " + d.seeds[0]);
    p.box.classList.toggle("vw-selected", typeof p.which === "number" && p.which === s.sampler);
    var shows = t ? (t.kind === "ref" ? "reference" : t.key + "/" + s.source + "/" + s.view) :
      "pending";
    p.canvas.setAttribute("data-shows", shows);
    if (!p.visible) return;
    var keys = self.keysFor(t);
    if (!self.need(keys)) {
      p.title.textContent += " \u00b7 " + (self.problem(keys) || "loading\u2026");
      return;
    }
    var sig = self.signature(t);
    if (p.sig === sig) return;
    self.draw(p.canvas, t, 0, 0, self.w, self.h);
    p.sig = sig;
    p.canvas.setAttribute("data-drawn", shows);
    if (t && !window.mcrtFirstImage) window.mcrtFirstImage = performance.now();
  });
  if (this.cropState.visible) this.crops.forEach(function (c) {
    var r = c.rect, t = self.target(c.which), sig = self.signature(t);
    if (self.need(self.keysFor(t)) && c.sig !== sig) {
      self.draw(c.canvas, t, r[0], r[1], r[2], r[2]);
      c.sig = sig;
    }
  });
  this.mark(this.samplerButtons, s.ref ? -1 : s.sampler);
  this.mark(this.sppButtons, s.spp);
  this.mark(this.sourceButtons, s.ref ? 2 : s.source === "mean" ? 1 : 0);
  this.mark(this.viewButtons, VIEWS.map(function (v) { return v[0]; }).indexOf(s.view));
  this.mark(this.layoutButtons, s.layout === "grid" ? 0 : 1);
  this.exposure.value = s.exposure;
  this.exposureText.textContent = (s.exposure > 0 ? "+" : "") + s.exposure + " EV";
  this.root.setAttribute("data-sampler", d.samplers[s.sampler]);
  this.root.setAttribute("data-spp", String(d.spp[s.spp]));
  this.root.setAttribute("data-view", s.view);
  this.root.setAttribute("data-zoom", String(s.zoom));
  var key = this.cellKey(s.sampler, s.spp), cell = d.cells[key];
  this.status.textContent = s.ref ? "reference, " + d.reference_spp + " spp" : !cell ?
    d.samplers[s.sampler] + " at " + d.spp[s.spp] + " spp: not measured (yet)" :
    d.samplers[s.sampler] + " at " + d.spp[s.spp] + " spp (effective " + cell.spp + "): MSE " +
    "\u2212 floor " + fmt(cell.mse_excess) + " (raw MSE " + fmt(cell.mse) + "), relMSE " + fmt(cell.rel_mse) + ", mean FLIP of seed " + d.seeds[0] +
    " " + fmt(cell.flip_mean) + "; zoom " + s.zoom + "\u00d7";
  this.drawColourbar();
  this.place();
  if (this.hover) this.inspect(this.hover.which, this.hover.x, this.hover.y);
};

Viewer.prototype.mark = function (buttons, index) {
  buttons.forEach(function (b, i) { b.classList.toggle("vw-on", i === index); });
};

Viewer.prototype.drawColourbar = function () {
  var view = this.s.view;
  if (view === "image") {
    this.colourbar.style.display = "none";
    return;
  }
  this.colourbar.style.display = "";
  var ctx = this.cbCanvas.getContext("2d"), img = ctx.createImageData(256, 1), rgb = [0, 0, 0];
  var map = view === "signed" ? "diverging" : view === "flip" ? "magma" : "viridis";
  for (var i = 0; i < 256; i++) {
    mapColour(map, i / 255, rgb);
    img.data[4 * i] = rgb[0]; img.data[4 * i + 1] = rgb[1]; img.data[4 * i + 2] = rgb[2];
    img.data[4 * i + 3] = 255;
  }
  ctx.putImageData(img, 0, 0);
  var max = this.scaleMax(), name = VIEWS.filter(function (v) { return v[0] === view; })[0][2];
  var lo = view === "signed" ? -max : 0, mid = view === "signed" ? 0 : max / 2;
  this.cbLabels.innerHTML = "";
  [fmt(lo), name + (view === "flip" ? " (seed " + this.data.seeds[0] + ")" : "") +
    (view === "variance" ? " across seeds" : "") + ": " + fmt(mid), fmt(max)]
    .forEach(function (t) { this.cbLabels.appendChild(el("span", "", t)); }, this);
};

Viewer.prototype.place = function () {
  var s = this.s, w = this.w * s.zoom, h = this.h * s.zoom;
  var pw = this.w * this.base, ph = this.h * this.base;
  // Keep some of the image in view.
  s.x = Math.round(Math.min(pw - 8, Math.max(8 - w, s.x)));
  s.y = Math.round(Math.min(ph - 8, Math.max(8 - h, s.y)));
  this.panels.forEach(function (p) {
    p.canvas.style.width = w + "px";
    p.canvas.style.height = h + "px";
    p.canvas.style.transform = "translate(" + s.x + "px," + s.y + "px)";
  });
};

Viewer.prototype.zoomAt = function (dir, cx, cy) {
  var s = this.s, old = s.zoom;
  var z = dir > 0 ? (old < 4 ? old + 1 : old * 2) : (old <= 4 ? old - 1 : old / 2);
  z = Math.max(1, Math.min(MAX_ZOOM, Math.round(z)));
  if (z === old) return;
  if (cx === undefined) { cx = this.w * this.base / 2; cy = this.h * this.base / 2; }
  // The image point under (cx, cy) stays there.
  s.x = cx - (cx - s.x) * z / old;
  s.y = cy - (cy - s.y) * z / old;
  s.zoom = z;
  this.render();
};

// ------------------------------------------------------------------ readout
Viewer.prototype.inspectEvent = function (p, e) {
  var r = p.canvas.getBoundingClientRect();
  var x = Math.floor((e.clientX - r.left) / this.s.zoom);
  var y = Math.floor((e.clientY - r.top) / this.s.zoom);
  if (x < 0 || y < 0 || x >= this.w || y >= this.h) return;
  this.inspect(p.which, x, y);
};

Viewer.prototype.inspect = function (which, x, y) {
  this.hover = {which: which, x: x, y: y};
  var d = this.data, s = this.s, i = y * this.w + x;
  var t = this.target(which), out = this.readout;
  out.setAttribute("data-x", String(x));
  out.setAttribute("data-y", String(y));
  var keys = this.keysFor(t, true);
  if (!this.need(keys)) {  // rendered (and inspected) again once they are here
    out.removeAttribute("data-ready");
    out.textContent = "pixel (" + x + ", " + y + "): " + (this.problem(keys) || "loading\u2026");
    return;
  }
  var ref = this.arrays.ref;
  out.innerHTML = "";
  function line(label, cls, values) {
    var row = el("div", "vw-row " + cls);
    row.appendChild(el("span", "vw-key", label));
    values.forEach(function (v) {
      var span = el("span", "vw-num", fmt(v));
      span.setAttribute("data-value", String(v));
      row.appendChild(span);
    });
    out.appendChild(row);
  }
  function rgbY(a) {
    return [a[3 * i], a[3 * i + 1], a[3 * i + 2],
            LUM[0] * a[3 * i] + LUM[1] * a[3 * i + 1] + LUM[2] * a[3 * i + 2]];
  }
  out.appendChild(el("div", "vw-row vw-where", "pixel (" + x + ", " + y + ") \u00b7 " +
    (!t ? "pending" : t.kind === "ref" ? "reference" : d.samplers[t.sampler] + " " +
     d.cells[t.key].spp + " spp, " + (s.source === "mean" ? "mean of " + d.seeds.length +
     " seeds" : "seed " + d.seeds[0])) + " \u00b7 R G B Y"));
  if (t && t.kind === "cell") line("value", "vw-value-row", rgbY(this.source(t)));
  line("reference", "vw-ref-row", rgbY(ref));
  if (t && t.kind === "cell") {
    line("sd across " + d.seeds.length + " seeds", "vw-sd-row",
         [Math.sqrt(this.arrays[t.key + "/variance"][i])]);
    if (s.view !== "image") {
      var name = VIEWS.filter(function (v) { return v[0] === s.view; })[0][2];
      line(name, "vw-err-row", [this.errorAt(t, i)]);
    }
  }
  out.setAttribute("data-ready", "1");
};
