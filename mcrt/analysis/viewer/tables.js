/* mcrt study report (see viewer.js): sortable tables, and the start of every viewer. */

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
    v.start();
    Array.prototype.forEach.call(root.querySelectorAll("table.sortable"), makeSortable);
  });
  active = viewers[0] || null;
  Array.prototype.forEach.call(document.querySelectorAll("table.sortable"), function (t) {
    if (!t.closest(".mcrt-viewer")) makeSortable(t);
  });
  window.mcrtViewers = viewers;
}

if (document.readyState === "loading") document.addEventListener("DOMContentLoaded", start);
else start();
