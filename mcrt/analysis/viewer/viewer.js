/* mcrt study report: the image viewer and sortable tables. No dependencies.
 * The data of each viewer: mcrt/analysis/viewer/__init__.py (float32 arrays,
 * byte-shuffled, zlib, base64). Every image is drawn at its native resolution
 * into a canvas and enlarged by CSS at an integer zoom with nearest-neighbour
 * sampling (image-rendering: pixelated): never resampled. */
(function () {
  "use strict";

  var LUM = [0.2126, 0.7152, 0.0722];
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

  function b64bytes(text) {
    var bin = atob(text), n = bin.length, out = new Uint8Array(n);
    for (var i = 0; i < n; i++) out[i] = bin.charCodeAt(i);
    return out;
  }

  function decode(text) {  // -> Promise<Float32Array>
    var stream = new Blob([b64bytes(text)]).stream()
      .pipeThrough(new DecompressionStream("deflate"));
    return new Response(stream).arrayBuffer().then(function (buf) {
      var src = new Uint8Array(buf), n = src.length / 4, out = new Uint8Array(src.length);
      for (var b = 0; b < 4; b++) {
        var off = b * n;
        for (var i = 0; i < n; i++) out[4 * i + b] = src[off + i];
      }
      return new Float32Array(out.buffer);
    });
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

  function percentile(values, q) {
    var a = values.filter(function (v) { return isFinite(v); });
    if (!a.length) return 1;
    a.sort(function (x, y) { return x - y; });
    return a[Math.min(a.length - 1, Math.floor(q * (a.length - 1)))];
  }

  var viewers = [], active = null;

  function Viewer(root) {
    this.root = root;
    this.data = JSON.parse(root.querySelector(".vw-data").textContent);
    var d = this.data;
    this.w = d.width; this.h = d.height;
    this.arrays = {};
    this.scales = {};
    var z = Math.max(1, Math.floor(320 / Math.max(d.width, d.height)));
    this.base = z;
    this.s = {sampler: 0, spp: Math.max(0, d.spp.indexOf(d.image_spp)), view: "image",
              source: "first", ref: false, layout: "grid", zoom: z, x: 0, y: 0,
              exposure: 0, errScale: 1};
    this.hover = null;
    root.mcrtViewer = this;
  }

  Viewer.prototype.load = function () {
    var self = this, d = this.data, jobs = [];
    function add(key, text) {
      jobs.push(decode(text).then(function (a) { self.arrays[key] = a; }));
    }
    add("ref", d.reference);
    Object.keys(d.cells).forEach(function (k) {
      ["first", "mean", "variance", "flip"].forEach(function (f) {
        add(k + "/" + f, d.cells[k][f]);
      });
    });
    return Promise.all(jobs).then(function () {
      self.build();
      self.render();
      self.root.setAttribute("data-ready", "1");
    }, function (err) {
      self.root.textContent = "Cannot decode the images (" + err + "); a browser with " +
        "DecompressionStream is needed (Chrome 80+, Firefox 113+, Safari 16.4+).";
    });
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
    root.addEventListener("mouseenter", function () { active = self; });
    root.addEventListener("focus", function () { active = self; });
  };

  Viewer.prototype.addPanel = function (which) {
    var self = this, p = {which: which};
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
        self.crops.push({canvas: cv, which: which, rect: c});
      });
      box.appendChild(row);
    });
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

  // Default colour-bar maximum of an error view: 99th percentile over every sampler at this spp.
  Viewer.prototype.scaleMax = function () {
    var view = this.s.view;
    if (view === "flip") return 1;
    var key = view + "/" + this.s.spp + "/" + this.s.source;
    if (!(key in this.scales)) {
      var values = [], n = this.w * this.h, step = Math.max(1, Math.floor(n / 20000));
      for (var s = 0; s < this.data.samplers.length; s++) {
        var k = this.cellKey(s, this.s.spp);
        if (!this.data.cells[k]) continue;
        for (var i = 0; i < n; i += step) values.push(Math.abs(this.errorAt({kind: "cell", key: k}, i)));
      }
      var p = percentile(values, 0.99);
      this.scales[key] = p > 0 ? p : 1;
    }
    return this.scales[key] * this.s.errScale;
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
      p.canvas.setAttribute("data-shows", t ? (t.kind === "ref" ? "reference" :
        t.key + "/" + s.source + "/" + s.view) : "pending");
      self.draw(p.canvas, t, 0, 0, self.w, self.h);
    });
    this.crops.forEach(function (c) {
      var r = c.rect;
      self.draw(c.canvas, self.target(c.which), r[0], r[1], r[2], r[2]);
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
    var d = this.data, s = this.s, i = y * this.w + x, ref = this.arrays.ref;
    var t = this.target(which), out = this.readout;
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
    out.setAttribute("data-x", String(x));
    out.setAttribute("data-y", String(y));
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

  // ------------------------------------------------------------------ sortable tables
  function cellValue(td) {
    var t = td.textContent.trim(), m = t.match(/^[-+]?(\d+\.?\d*|\.\d+)([eE][-+]?\d+)?/);
    return m ? parseFloat(m[0]) : t.toLowerCase();
  }

  function makeSortable(table) {
    var heads = table.querySelectorAll("thead th");
    Array.prototype.forEach.call(heads, function (th, col) {
      th.classList.add("vw-sort");
      th.title = "click to sort";
      th.addEventListener("click", function () {
        var body = table.tBodies[0], rows = Array.prototype.slice.call(body.rows);
        var dir = th.getAttribute("data-dir") === "asc" ? -1 : 1;
        Array.prototype.forEach.call(heads, function (h) { h.removeAttribute("data-dir"); });
        th.setAttribute("data-dir", dir > 0 ? "asc" : "desc");
        rows.sort(function (a, b) {
          var x = cellValue(a.cells[col]), y = cellValue(b.cells[col]);
          if (typeof x !== typeof y) return (typeof x === "number" ? -1 : 1);
          return (x < y ? -1 : x > y ? 1 : 0) * dir;
        });
        rows.forEach(function (r) { body.appendChild(r); });
      });
    });
  }

  function start() {
    Array.prototype.forEach.call(document.querySelectorAll(".mcrt-viewer"), function (root) {
      var v = new Viewer(root);
      viewers.push(v);
      v.load().then(function () {
        Array.prototype.forEach.call(root.querySelectorAll("table.sortable"), makeSortable);
      });
    });
    active = viewers[0] || null;
    Array.prototype.forEach.call(document.querySelectorAll("table.sortable"), function (t) {
      if (!t.closest(".mcrt-viewer")) makeSortable(t);
    });
    window.mcrtViewers = viewers;
  }

  if (document.readyState === "loading") document.addEventListener("DOMContentLoaded", start);
  else start();
})();
