/* pd-analyze HTML report, part 1: the tables (sort, filter, page). Data from the page's JSON, text set with
   textContent only. Part 2 (drill.js) opens a transaction's frames from any txn link. */
var PD = (function () {
  "use strict";
  var DATA = JSON.parse(document.getElementById("pd-data").textContent);
  var PAGE = DATA.page;
  var CLASS = {verdict: "v", severity: "s"};
  var TIME_TEMPLATE = "0000-01-01 00:00:00.000000000";  /* cells have a capture's decimals: 0 to 9 */

  function el(tag, text, cls) {
    var e = document.createElement(tag);
    if (text !== undefined && text !== null) { e.textContent = String(text); }
    if (cls) { e.className = cls; }
    return e;
  }
  function isNum(kind) { return kind === "num" || kind === "ms"; }
  function shown(v) { return v === null ? "" : String(v); }
  function compareOp(op, a, b) {
    return op === "<" ? a < b : op === ">" ? a > b : op === "<=" ? a <= b : op === ">=" ? a >= b : a === b;
  }

  /* A time cell padded to the full width (nine decimals), so that cells of any resolution compare as times. */
  function fullTime(text) {
    return text + TIME_TEMPLATE.slice(text.length);
  }
  /* A time typed in a filter as the cells hold it ("2026-01-01 00:00:05" or a time of day "00:00:05.5"):
     [the text padded to the full width, whether it is a time of day], or null. */
  function timeKey(text) {
    if (/^\d{4}-\d\d(-\d\d( \d\d(:\d\d(:\d\d(\.\d{1,9})?)?)?)?)?$/.test(text)) {
      return [text + TIME_TEMPLATE.slice(text.length), false];
    }
    var m = /^(\d{1,2}):(\d\d)(?::(\d\d)(\.\d{1,9})?)?$/.exec(text);
    if (!m) { return null; }
    var day = ("0" + m[1]).slice(-2) + ":" + m[2] + ":" + (m[3] || "00") + (m[4] || ".");
    return [day + TIME_TEMPLATE.slice(11 + day.length), true];
  }

  function parseFilter(text, kind) {
    if (!text) { return null; }
    var neg = false;
    if (text.charAt(0) === "!") { neg = true; text = text.slice(1); }
    var m = /^(<=|>=|<|>|=)\s*(.*)$/.exec(text), test = null;
    var rest = m ? m[2] : text, op = m ? m[1] : "=";
    var number = rest !== "" && !isNaN(Number(rest)) ? Number(rest) : null;
    if (isNum(kind) && number !== null) {  /* a number: compared, a bare one exactly */
      test = function (v) { return v !== null && compareOp(op, v, number); };
    } else if (kind === "frames" && number !== null) {  /* any frame of the list */
      test = function (v) {
        if (v === null) { return false; }
        var frames = String(v).split(" ");
        for (var k = 0; k < frames.length; k++) { if (compareOp(op, Number(frames[k]), number)) { return true; } }
        return false;
      };
    } else if (kind === "time" && m && m[1] !== "=" && timeKey(rest)) {
      var key = timeKey(rest);
      test = function (v) {
        return v !== null && compareOp(op, key[1] ? fullTime(String(v)).slice(11) : fullTime(String(v)), key[0]);
      };
    } else if (m && m[1] === "=") {
      var exact = rest.toLowerCase();
      test = function (v) { return shown(v).toLowerCase() === exact; };
    } else {
      var needle = text.toLowerCase();
      test = function (v) { return shown(v).toLowerCase().indexOf(needle) >= 0; };
    }
    return neg ? function (v) { return !test(v); } : test;
  }

  function compare(kind, dir) {
    return function (a, b) {  /* empty cells last in either direction */
      if (a === null || a === "") { return (b === null || b === "") ? 0 : 1; }
      if (b === null || b === "") { return -1; }
      if (isNum(kind)) { return dir * (a - b); }
      return dir * String(a).localeCompare(String(b), undefined, {numeric: true});
    };
  }

  function txnLink(v) {
    var a = el("a", v);
    a.href = "#txn-" + v;
    a.title = "the frames of transaction " + v;
    return a;
  }

  function makeTable(host, spec) {
    var cols = spec.columns, rows = spec.rows;
    var state = {sort: -1, dir: 1, tests: cols.map(function () { return null; }), page: 0, size: PAGE};
    var table = el("table"), thead = table.createTHead();
    var hrow = thead.insertRow(), frow = thead.insertRow();
    frow.className = "filters";
    var heads = [];
    cols.forEach(function (c, i) {
      var th = el("th", c.label, "sortable");
      th.setAttribute("data-col", c.name);
      th.setAttribute("aria-sort", "none");
      th.tabIndex = 0;
      th.title = "sort by " + c.label;
      th.addEventListener("click", function () { sortBy(i); });
      th.addEventListener("keydown", function (e) { if (e.key === "Enter") { sortBy(i); } });
      hrow.appendChild(th);
      heads.push(th);
      var fth = el("th"), input = el("input");
      input.type = "search";
      input.placeholder = isNum(c.kind) || c.kind === "time" ? "> < =" : c.kind === "frames" ? "frame" : "filter";
      input.setAttribute("aria-label", "filter " + c.label);
      input.setAttribute("data-col", c.name);
      input.addEventListener("input", function () {
        state.tests[i] = parseFilter(input.value.trim(), c.kind);
        state.page = 0;
        draw();
      });
      fth.appendChild(input);
      frow.appendChild(fth);
    });
    var tbody = table.createTBody();
    var wrap = el("div", null, "wrap");
    wrap.appendChild(table);
    var pager = el("div", null, "pager"), info = el("span");
    var first = el("button", "\u00ab first"), prev = el("button", "\u2039 previous");
    var next = el("button", "next \u203a"), last = el("button", "last \u00bb");
    var size = el("select");
    [25, 50, 100, 500, 5000].forEach(function (n) {
      var o = el("option", n + " rows per page");
      o.value = n;
      if (n === PAGE) { o.selected = true; }
      size.appendChild(o);
    });
    [first, prev, next, last, size, info].forEach(function (x) { pager.appendChild(x); });
    host.appendChild(pager);
    host.appendChild(wrap);
    var view = [];

    function sortBy(i) {
      state.dir = state.sort === i ? -state.dir : 1;
      state.sort = i;
      heads.forEach(function (th, k) {
        th.setAttribute("aria-sort", k !== i ? "none" : state.dir > 0 ? "ascending" : "descending");
      });
      state.page = 0;
      draw();
    }
    function pages() { return Math.max(1, Math.ceil(view.length / state.size)); }
    first.addEventListener("click", function () { state.page = 0; page(); });
    prev.addEventListener("click", function () { state.page = Math.max(0, state.page - 1); page(); });
    next.addEventListener("click", function () { state.page = Math.min(pages() - 1, state.page + 1); page(); });
    last.addEventListener("click", function () { state.page = pages() - 1; page(); });
    size.addEventListener("change", function () { state.size = Number(size.value); state.page = 0; page(); });

    function draw() {
      view = [];
      for (var r = 0; r < rows.length; r++) {
        var keep = true;
        for (var i = 0; i < cols.length && keep; i++) {
          if (state.tests[i] && !state.tests[i](rows[r][i])) { keep = false; }
        }
        if (keep) { view.push(r); }
      }
      if (state.sort >= 0) {
        var i = state.sort, cmp = compare(cols[i].kind, state.dir);
        view.sort(function (a, b) { return cmp(rows[a][i], rows[b][i]) || a - b; });
      }
      page();
    }
    function page() {
      var start = state.page * state.size, end = Math.min(view.length, start + state.size);
      var frag = document.createDocumentFragment();
      for (var k = start; k < end; k++) {
        var row = rows[view[k]], tr = document.createElement("tr");
        for (var i = 0; i < cols.length; i++) {
          var c = cols[i], v = row[i], td = el("td", null, isNum(c.kind) ? "num" : "");
          if (CLASS[c.kind] && v !== null) { td.className = CLASS[c.kind] + " " + CLASS[c.kind] + "-" + v; }
          if (c.name === "txn" && v !== null) {
            td.appendChild(txnLink(v));
          } else {
            td.textContent = shown(v);
            if (td.textContent.length > 30) { td.title = td.textContent; }  /* a cut cell: its full text */
          }
          tr.appendChild(td);
        }
        frag.appendChild(tr);
      }
      tbody.replaceChildren(frag);
      var filtered = view.length < rows.length ? " (filtered from " + rows.length.toLocaleString("en") + ")" : "";
      info.textContent = view.length ? "rows " + (start + 1).toLocaleString("en") + "\u2013" +
        end.toLocaleString("en") + " of " + view.length.toLocaleString("en") + filtered :
        "no row matches" + filtered;
      host.setAttribute("data-visible", String(end - start));
      host.setAttribute("data-matching", String(view.length));
      first.disabled = prev.disabled = state.page === 0;
      next.disabled = last.disabled = state.page >= pages() - 1;
    }
    draw();
  }

  document.querySelectorAll("div.pdtable").forEach(function (host) {
    makeTable(host, DATA.tables[host.getAttribute("data-table")]);
  });
  return {DATA: DATA, el: el};
})();
