/* mcrt study report, the viewer's images (see viewer.js): one file per image beside the
 * report (mcrt/analysis/viewer/data.py: float16 scaled by a power of two, byte-shuffled,
 * zlib, the bytes as a windows-1252 string in a call of window.mcrtData), loaded by a
 * <script src> (fetch() of local files is refused from file://) when a panel that shows the
 * image comes into view, and dropped again, least recently used first, when the images held
 * exceed MAX_BYTES. */

// Bytes of decoded images kept by all viewers together; beyond it the least recently used
// images not on screen are dropped (and loaded again when shown again). A page (a test) may
// set window.mcrtMaxBytes instead.
var MAX_BYTES = 768 * 1024 * 1024;
// float16 -> its value, for every 16-bit pattern.
var HALF = (function () {
  var t = new Float32Array(65536);
  for (var h = 0; h < 65536; h++) {
    var e = (h >> 10) & 31, m = h & 1023;
    var v = e === 0 ? m * Math.pow(2, -24) : e === 31 ? (m ? NaN : Infinity) :
      (1024 + m) * Math.pow(2, e - 25);
    t[h] = h & 0x8000 ? -v : v;
  }
  return t;
})();

// The byte of each character of a data file's payload, read as windows-1252: bytes
// 0x80-0x9f are these characters, every other byte the character of its own code.
var CP1252 = [0x20AC, 0x81, 0x201A, 0x192, 0x201E, 0x2026, 0x2020, 0x2021, 0x2C6, 0x2030,
              0x160, 0x2039, 0x152, 0x8D, 0x17D, 0x8F, 0x90, 0x2018, 0x2019, 0x201C, 0x201D,
              0x2022, 0x2013, 0x2014, 0x2DC, 0x2122, 0x161, 0x203A, 0x153, 0x9D, 0x17E, 0x178];
var BYTE = (function () {
  var t = new Uint8Array(0x2200);
  for (var c = 0; c < 256; c++) t[c] = c;
  CP1252.forEach(function (c, i) { t[c] = 0x80 + i; });
  return t;
})();

function payloadBytes(text) {
  var n = text.length, out = new Uint8Array(n);
  for (var i = 0; i < n; i++) out[i] = BYTE[text.charCodeAt(i)];
  return out;
}

// A data file's payload -> Promise<Float32Array> of the values it holds.
function decode(text, exponent) {
  if (typeof DecompressionStream === "undefined") {
    return Promise.reject("this browser has no DecompressionStream (Chrome 80+, " +
                          "Firefox 113+, Safari 16.4+ have it)");
  }
  var stream = new Blob([payloadBytes(text)]).stream()
    .pipeThrough(new DecompressionStream("deflate"));
  return new Response(stream).arrayBuffer().then(function (buf) {
    var src = new Uint8Array(buf), n = src.length >> 1, out = new Float32Array(n);
    var scale = Math.pow(2, -exponent);
    for (var i = 0; i < n; i++) out[i] = HALF[src[i] | (src[n + i] << 8)] * scale;
    return out;
  });
}

// ------------------------------------------------------------------ loading
// A data file calls window.mcrtData(url, [h, w, c], exponent, payload) when its <script>
// runs; loadFile(url, callback) adds that script once and calls every callback waiting
// for it with (Float32Array) or (null, why not).
var files = {};
var held = [], heldBytes = 0, clock = 0;

window.mcrtData = function (url, shape, exponent, text) {
  var f = files[url];
  if (!f || f.called) return;
  f.called = true;
  if (f.script.parentNode) f.script.parentNode.removeChild(f.script);
  decode(text, exponent).then(function (a) {
    delete files[url];
    f.callbacks.forEach(function (cb) { cb(a); });
  }, function (err) {
    delete files[url];
    f.callbacks.forEach(function (cb) { cb(null, String(err)); });
  });
};

function loadFile(url, callback) {
  var f = files[url];
  if (f) { f.callbacks.push(callback); return; }
  f = files[url] = {callbacks: [callback], called: false};
  function fail(why) {
    delete files[url];
    f.callbacks.forEach(function (cb) { cb(null, why); });
  }
  f.script = document.createElement("script");
  f.script.charset = "windows-1252";
  f.script.src = url;
  f.script.onerror = function () { fail("cannot read " + url); };
  f.script.onload = function () { if (!f.called) fail(url + " holds no image"); };
  document.head.appendChild(f.script);
}

function budget() { return window.mcrtMaxBytes > 0 ? window.mcrtMaxBytes : MAX_BYTES; }
window.mcrtHeldBytes = function () { return heldBytes; };

// Drop the least recently used images that no viewer shows until the rest fit the budget.
function evict() {
  held.sort(function (x, y) { return x.viewer.used[x.key] - y.viewer.used[y.key]; });
  for (var i = 0; i < held.length && heldBytes > budget();) {
    var v = held[i].viewer, key = held[i].key;
    if (v.pins[key]) { i++; continue; }
    heldBytes -= v.arrays[key].byteLength;
    delete v.arrays[key];
    held.splice(i, 1);
  }
}

// The URL of image `key` ("ref" or "<sampler>/<spp>/<kind>"), or null.
Viewer.prototype.url = function (key) {
  if (key === "ref") return this.data.reference;
  var i = key.lastIndexOf("/"), cell = this.data.cells[key.slice(0, i)];
  return cell && cell.data ? cell.data[key.slice(i + 1)] || null : null;
};

// True when every image of `keys` is held; else loads the missing ones (the viewer
// renders again as each arrives) and returns false.
Viewer.prototype.need = function (keys) {
  var self = this, ready = true;
  keys.forEach(function (key) {
    self.pins[key] = true;
    if (self.arrays[key]) { self.used[key] = ++clock; return; }
    ready = false;
    if (self.loading[key] || self.failed[key]) return;
    var url = self.url(key);
    if (!url) { self.failed[key] = "no image " + key; return; }
    self.loading[key] = true;
    self.root.setAttribute("data-requested", String(++self.requested));
    loadFile(url, function (a, why) {
      delete self.loading[key];
      var n = self.w * self.h * (/\/(variance|flip)$/.test(key) ? 1 : 3);
      if (a && a.length !== n) { a = null; why = url + " is not this report's image"; }
      if (a) self.hold(key, a); else self.failed[key] = why;
      self.schedule();
    });
  });
  return ready;
};

// Why one of `keys` cannot be shown ("" when none failed).
Viewer.prototype.problem = function (keys) {
  for (var i = 0; i < keys.length; i++) if (this.failed[keys[i]]) return this.failed[keys[i]];
  return "";
};

Viewer.prototype.hold = function (key, a) {
  this.arrays[key] = a;
  this.used[key] = ++clock;
  this.root.setAttribute("data-loaded", String(++this.loaded));
  held.push({viewer: this, key: key});
  heldBytes += a.byteLength;
  if (heldBytes > budget()) evict();
};

Viewer.prototype.schedule = function () {
  var self = this;
  if (this.scheduled) return;
  this.scheduled = true;
  setTimeout(function () { self.scheduled = false; self.render(); }, 0);
};

// The images that showing target t (or its readout) in the current view needs.
Viewer.prototype.keysFor = function (t, readout) {
  if (!t) return [];
  if (t.kind === "ref") return ["ref"];
  var view = this.s.view, src = t.key + "/" + this.s.source;
  if (readout) return [src, "ref", t.key + "/variance"].concat(
    view === "flip" ? [t.key + "/flip"] : []);
  if (view === "image") return [src];
  if (view === "flip" || view === "variance") return [t.key + "/" + view];
  return [src, "ref"];
};

// What a canvas showing target t looks like now: it is drawn again when this changes.
Viewer.prototype.signature = function (t) {
  if (!t) return "pending";
  if (t.kind === "ref") return "reference|" + this.s.exposure;
  var s = this.s;
  return t.key + "/" + s.source + "/" + s.view + "|" + s.exposure + "|" +
    (s.view === "image" ? "" : this.scaleMax());
};
