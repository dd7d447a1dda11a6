/* mcrt study report: the image viewer, one per scene (no dependencies).
 * The report inlines viewer.js, loading.js, pixels.js and tables.js, in that order, into one
 * function scope (mcrt/analysis/viewer/__init__.py, viewer_assets). This part: the constants,
 * the viewer's state, its DOM (toolbar, panels, crops, EXR links) and its keys.
 * The data of each viewer: a JSON skeleton in the page (mcrt/analysis/viewer/__init__.py)
 * and one file per image beside it (loading.js). Every image is drawn at its native
 * resolution into a canvas and enlarged by CSS at an integer zoom with nearest-neighbour
 * sampling (image-rendering: pixelated): never resampled (pixels.js). */

// LUM, the luminance weights of linear R, G, B, is defined by the page: viewer_assets writes
// mcrt.core.colour.LUMINANCE_WEIGHTS before these scripts.
var REL_EPS = 0.01;
var VIEWS = [
  ["image", "i", "image"], ["signed", "s", "signed error"], ["abs", "a", "absolute error"],
  ["rel", "e", "relative error"], ["flip", "f", "FLIP"], ["variance", "v", "variance"]];
var VIEW_KEYS = {};
VIEWS.forEach(function (v) { VIEW_KEYS[v[1]] = v[0]; });
var NONFINITE = [255, 0, 255];
var MAX_ZOOM = 64;

// Colour maps: control points (0..1) interpolated linearly.
var MAPS = {
  viridis: [[68, 1, 84], [72, 40, 120], [62, 74, 137], [49, 104, 142], [38, 130, 142],
            [31, 158, 137], [53, 183, 121], [109, 205, 89], [180, 222, 44], [253, 231, 37]],
  magma: [[0, 0, 4], [28, 16, 68], [79, 18, 123], [129, 37, 129], [181, 54, 122],
          [229, 80, 100], [251, 135, 97], [254, 194, 135], [252, 253, 191]],
  diverging: [[5, 48, 97], [33, 102, 172], [67, 147, 195], [146, 197, 222], [209, 229, 240],
              [247, 247, 247], [253, 219, 199], [244, 165, 130], [214, 96, 77],
              [178, 24, 43], [103, 0, 31]]
};

function mapColour(name, t, out) {
  var m = MAPS[name];
  if (!(t >= 0)) t = 0;
  if (t > 1) t = 1;
  var f = t * (m.length - 1), i = Math.min(Math.floor(f), m.length - 2), u = f - i;
  for (var c = 0; c < 3; c++) out[c] = m[i][c] + (m[i + 1][c] - m[i][c]) * u;
  return out;
}

function srgb(v) {
  if (!(v > 0)) return 0;
  v = v <= 0.0031308 ? 12.92 * v : 1.055 * Math.pow(v, 1 / 2.4) - 0.055;
  return v >= 1 ? 255 : v * 255;
}

function fmt(v) {
  if (v === null || v === undefined) return "\u2013";
  if (!isFinite(v)) return String(v);
  if (v === 0) return "0";
  var a = Math.abs(v);
  return (a >= 1e-3 && a < 1e5) ? String(Number(v.toPrecision(6))) : v.toExponential(5);
}

function el(tag, cls, text) {
  var e = document.createElement(tag);
  if (cls) e.className = cls;
  if (text !== undefined) e.textContent = text;
  return e;
}

var viewers = [], active = null;

function Viewer(root) {
  this.root = root;
  this.data = JSON.parse(root.querySelector(".vw-data").textContent);
  var d = this.data;
  this.w = d.width; this.h = d.height;
  this.arrays = {};      // decoded images by key: "ref", "<sampler>/<spp>/<kind>"
  this.used = {};        // key -> when last needed (for evict)
  this.loading = {};
  this.failed = {};      // key -> why it cannot be shown
  this.pins = {};        // the images the last render needed
  this.requested = 0;
  this.loaded = 0;
  var z = Math.max(1, Math.floor(320 / Math.max(d.width, d.height)));
  this.base = z;
  this.s = {sampler: 0, spp: Math.max(0, d.spp.indexOf(d.image_spp)), view: "image",
            source: "first", ref: false, layout: "grid", zoom: z, x: 0, y: 0,
            exposure: 0, errScale: 1};
  this.hover = null;
  root.mcrtViewer = this;
}

Viewer.prototype.start = function () {
  this.build();
  this.render();
  this.root.setAttribute("data-ready", "1");
};

Viewer.prototype.cellKey = function (sampler, spp) {
  return this.data.samplers[sampler] + "/" + this.data.spp[spp];
};

// ------------------------------------------------------------------ DOM
Viewer.prototype.build = function () {
  var self = this, d = this.data, root = this.root;
  var bar = el("div", "vw-toolbar");
  function group(label, items, onclick) {
    var g = el("span", "vw-group");
    g.appendChild(el("span", "vw-label", label));
    var buttons = items.map(function (item, i) {
      var b = el("button", "vw-btn", item[0]);
      b.type = "button";
      b.title = item[1];
      b.addEventListener("click", function () { onclick(i); self.render(); });
      g.appendChild(b);
      return b;
    });
    bar.appendChild(g);
    return buttons;
  }
  this.samplerButtons = group("sampler", d.samplers.map(function (s, i) {
    return [s, "key " + (i + 1)];
  }), function (i) { self.s.sampler = i; self.s.ref = false; });
  this.sppButtons = group("spp", d.spp.map(function (n) { return [String(n), "\u2190 \u2192"]; }),
    function (i) { self.s.spp = i; });
  this.sourceButtons = group("image", [["seed " + d.seeds[0], "m"],
    ["mean of " + d.seeds.length, "m"], ["reference", "r"]], function (i) {
    if (i === 2) self.s.ref = !self.s.ref; else { self.s.source = i ? "mean" : "first"; self.s.ref = false; }
  });
  this.viewButtons = group("view", VIEWS.map(function (v) { return [v[2], "key " + v[1]]; }),
    function (i) { self.s.view = VIEWS[i][0]; });
  var ex = el("span", "vw-group");
  ex.appendChild(el("span", "vw-label", "exposure"));
  this.exposure = el("input", "vw-exposure");
  this.exposure.type = "range"; this.exposure.min = -10; this.exposure.max = 10;
  this.exposure.step = 0.5; this.exposure.value = 0;
  this.exposure.addEventListener("input", function () {
    self.s.exposure = parseFloat(self.exposure.value); self.render();
  });
  ex.appendChild(this.exposure);
  this.exposureText = el("span", "vw-value", "0");
  ex.appendChild(this.exposureText);
  bar.appendChild(ex);
  this.layoutButtons = group("layout", [["grid", "g"], ["one", "g"]],
    function (i) { self.s.layout = i ? "single" : "grid"; });
  root.appendChild(bar);
  root.appendChild(el("div", "vw-help", root.getAttribute("data-help") || ""));
  this.status = el("div", "vw-status");
  root.appendChild(this.status);

  this.panelBox = el("div", "vw-panels");
  this.panels = [];
  this.addPanel("ref");
  for (var i = 0; i < d.samplers.length; i++) this.addPanel(i);
  this.addPanel("selected");
  root.appendChild(this.panelBox);

  this.colourbar = el("div", "vw-colourbar");
  this.cbCanvas = el("canvas");
  this.cbCanvas.width = 256; this.cbCanvas.height = 1;
  this.cbLabels = el("div", "vw-cb-labels");
  this.colourbar.appendChild(this.cbCanvas);
  this.colourbar.appendChild(this.cbLabels);
  root.appendChild(this.colourbar);
  this.readout = el("div", "vw-readout", "Hover a pixel for its values.");
  root.appendChild(this.readout);
  this.buildCrops();
  this.buildLinks();
  this.observe();
  root.addEventListener("mouseenter", function () { active = self; });
  root.addEventListener("focus", function () { active = self; });
};

// Panels and crops load and draw their images only while on screen (or near it).
Viewer.prototype.observe = function () {
  var self = this, watched = this.panels.slice();
  this.cropState = {visible: false};
  if (this.cropBox) { this.cropBox.mcrtState = this.cropState; }
  if (!window.IntersectionObserver) {
    watched.forEach(function (p) { p.visible = true; });
    this.cropState.visible = true;
    return;
  }
  var observer = new IntersectionObserver(function (entries) {
    entries.forEach(function (e) { e.target.mcrtState.visible = e.isIntersecting; });
    self.schedule();
  }, {rootMargin: "200px"});
  watched.forEach(function (p) { p.box.mcrtState = p; observer.observe(p.box); });
  if (this.cropBox) observer.observe(this.cropBox);
};

Viewer.prototype.addPanel = function (which) {
  var self = this, p = {which: which, visible: false, sig: null};
  p.box = el("div", "vw-panel");
  p.title = el("div", "vw-title");
  p.port = el("div", "vw-port");
  p.canvas = el("canvas", "vw-canvas");
  p.canvas.width = this.w; p.canvas.height = this.h;
  p.port.style.width = (this.w * this.base) + "px";
  p.port.style.height = (this.h * this.base) + "px";
  p.port.appendChild(p.canvas);
  p.box.appendChild(p.title);
  p.box.appendChild(p.port);
  p.box.setAttribute("data-panel", String(which));
  this.panelBox.appendChild(p.box);
  this.panels.push(p);
  var drag = null;
  p.port.addEventListener("mousedown", function (e) {
    drag = {x: e.clientX, y: e.clientY, sx: self.s.x, sy: self.s.y, moved: false};
    e.preventDefault();
    active = self;
    self.root.focus({preventScroll: true});
  });
  window.addEventListener("mousemove", function (e) {
    if (!drag) return;
    var dx = e.clientX - drag.x, dy = e.clientY - drag.y;
    if (Math.abs(dx) + Math.abs(dy) > 2) drag.moved = true;
    self.s.x = drag.sx + dx; self.s.y = drag.sy + dy;
    self.place();
  });
  window.addEventListener("mouseup", function () {
    if (drag && !drag.moved && typeof p.which === "number") {
      self.s.sampler = p.which; self.s.ref = false; self.render();
    }
    drag = null;
  });
  p.port.addEventListener("mousemove", function (e) { self.inspectEvent(p, e); });
  p.port.addEventListener("wheel", function (e) {
    e.preventDefault();
    var r = p.port.getBoundingClientRect();
    self.zoomAt(e.deltaY < 0 ? 1 : -1, e.clientX - r.left, e.clientY - r.top);
  }, {passive: false});
};

Viewer.prototype.buildCrops = function () {
  var self = this, d = this.data;
  this.crops = [];
  if (!d.crops.length) return;
  var box = el("div", "vw-crops");
  box.appendChild(el("div", "vw-subhead", "Hardest regions (largest squared error of seed " +
    d.seeds[0] + " at " + d.image_spp + " spp, averaged over samplers); they follow the " +
    "spp, image, view and exposure chosen above."));
  d.crops.forEach(function (c, n) {
    var row = el("div", "vw-crop-row");
    row.appendChild(el("div", "vw-crop-label", "crop " + (n + 1) + ": x " + c[0] + "\u2013" +
      (c[0] + c[2] - 1) + ", y " + c[1] + "\u2013" + (c[1] + c[2] - 1)));
    var zoom = Math.max(1, Math.floor(128 / c[2]));
    ["ref"].concat(d.samplers.map(function (_, i) { return i; })).forEach(function (which) {
      var cell = el("div", "vw-crop");
      var cv = el("canvas", "vw-canvas");
      cv.width = c[2]; cv.height = c[2];
      cv.style.width = (c[2] * zoom) + "px"; cv.style.height = (c[2] * zoom) + "px";
      cell.appendChild(cv);
      cell.appendChild(el("div", "vw-crop-name", which === "ref" ? "reference" : d.samplers[which]));
      row.appendChild(cell);
      self.crops.push({canvas: cv, which: which, rect: c, sig: null});
    });
    box.appendChild(row);
  });
  this.cropBox = box;
  this.root.appendChild(box);
};

Viewer.prototype.buildLinks = function () {
  var d = this.data, box = el("details", "vw-links");
  box.appendChild(el("summary", "", "EXR files (mean over seeds with its variance layer, " +
    "and seed " + d.seeds[0] + ")"));
  var t = el("table", "sortable"), head = el("tr");
  ["sampler"].concat(d.spp.map(function (n) { return n + " spp"; })).forEach(function (h) {
    head.appendChild(el("th", "", h));
  });
  var thead = el("thead"); thead.appendChild(head); t.appendChild(thead);
  var body = el("tbody");
  d.samplers.forEach(function (s) {
    var tr = el("tr");
    tr.appendChild(el("td", "", s));
    d.spp.forEach(function (n) {
      var td = el("td"), cell = d.cells[s + "/" + n];
      if (cell && cell.exr && cell.exr.mean) {
        var a = el("a", "", "mean"); a.href = cell.exr.mean; td.appendChild(a);
        td.appendChild(document.createTextNode(" \u00b7 "));
        var b = el("a", "", "seed " + d.seeds[0]); b.href = cell.exr.first; td.appendChild(b);
      } else td.textContent = "pending";
      tr.appendChild(td);
    });
    body.appendChild(tr);
  });
  t.appendChild(body);
  box.appendChild(t);
  if (d.reference_exr) {
    var p = el("p"), a = el("a", "", "reference (" + d.reference_spp + " spp)");
    a.href = d.reference_exr; p.appendChild(a); box.appendChild(p);
  }
  this.root.appendChild(box);
};

// ------------------------------------------------------------------ keys
Viewer.prototype.key = function (e) {
  var s = this.s, d = this.data, k = e.key;
  if (k >= "1" && k <= "9" && +k <= d.samplers.length) { s.sampler = +k - 1; s.ref = false; }
  else if (k === "ArrowDown") { s.sampler = (s.sampler + 1) % d.samplers.length; s.ref = false; }
  else if (k === "ArrowUp") { s.sampler = (s.sampler + d.samplers.length - 1) % d.samplers.length; s.ref = false; }
  else if (k === "ArrowRight") s.spp = Math.min(d.spp.length - 1, s.spp + 1);
  else if (k === "ArrowLeft") s.spp = Math.max(0, s.spp - 1);
  else if (k === "r") s.ref = !s.ref;
  else if (k === "m") s.source = s.source === "mean" ? "first" : "mean";
  else if (k in VIEW_KEYS) s.view = VIEW_KEYS[k];
  else if (k === "+" || k === "=") { this.zoomAt(1); return true; }
  else if (k === "-" || k === "_") { this.zoomAt(-1); return true; }
  else if (k === "0") { s.zoom = this.base; s.x = 0; s.y = 0; }
  else if (k === "]") s.exposure = Math.min(10, s.exposure + 0.5);
  else if (k === "[") s.exposure = Math.max(-10, s.exposure - 0.5);
  else if (k === "x") s.exposure = 0;
  else if (k === "}") s.errScale *= 2;
  else if (k === "{") s.errScale /= 2;
  else if (k === "g") s.layout = s.layout === "grid" ? "single" : "grid";
  else return false;
  this.render();
  return true;
};

document.addEventListener("keydown", function (e) {
  if (!active || e.ctrlKey || e.metaKey || e.altKey) return;
  var tag = e.target && e.target.tagName;
  if (tag === "INPUT" && e.target.type !== "range") return;
  if (tag === "TEXTAREA" || tag === "SELECT") return;
  if (active.key(e)) e.preventDefault();
});
