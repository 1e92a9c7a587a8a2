
(function () {
  "use strict";
  var DATA = JSON.parse(document.getElementById("pd-data").textContent);
  var PAGE = DATA.page;
  var CLASS = {verdict: "v", severity: "s"};

  function el(tag, text, cls) {
    var e = document.createElement(tag);
    if (text !== undefined && text !== null) { e.textContent = String(text); }
    if (cls) { e.className = cls; }
    return e;
  }
  function isNum(kind) { return kind === "num" || kind === "ms"; }
  function shown(v) { return v === null ? "" : String(v); }

  function parseFilter(text, kind) {
    if (!text) { return null; }
    var neg = false;
    if (text.charAt(0) === "!") { neg = true; text = text.slice(1); }
    var m = /^(<=|>=|<|>|=)\s*(.*)$/.exec(text), test;
    if (m && isNum(kind) && m[2] !== "" && !isNaN(Number(m[2]))) {
      var n = Number(m[2]), op = m[1];
      test = function (v) {
        if (v === null) { return false; }
        return op === "<" ? v < n : op === ">" ? v > n : op === "<=" ? v <= n : op === ">=" ? v >= n : v === n;
      };
    } else if (m && m[1] === "=") {
      var exact = m[2].toLowerCase();
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

  function makeTable(host, spec) {
    var cols = spec.columns, rows = spec.rows;
    var links = {};
    (spec.links || []).forEach(function (t) { links[t] = true; });
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
      input.placeholder = isNum(c.kind) ? "> < =" : "filter";
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
          if (c.name === "txn" && v !== null && links[v]) {
            var a = el("a", v);
            a.href = "#txn-" + v;
            td.appendChild(a);
          } else {
            td.textContent = shown(v);
            if (td.textContent.length > 40) { td.title = td.textContent; }  /* cut with an ellipsis */
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

  function drawFrames(box, frames) {
    if (!frames || !frames.length) {
      box.appendChild(el("p", "No frame of this transaction was found again in the capture.", "dim"));
      return;
    }
    frames.forEach(function (f) {
      if (f.gap) {
        box.appendChild(el("p", "\u2026 " + f.gap + " frames left out \u2026", "gap"));
        return;
      }
      var div = el("div", null, "frame");
      div.appendChild(el("div", "Frame " + f.n + "  " + f.t + "  " + f.src + " \u2192 " + f.dst + "  " + f.s,
        "fhead"));
      var table = el("table", null, "fields"), body = table.createTBody();
      f.L.forEach(function (layer) {
        var tr = body.insertRow(), td = el("td", layer[0]);
        td.colSpan = 5;
        td.style.paddingLeft = (layer[1] * 14) + "px";
        tr.className = "layer";
        tr.appendChild(td);
        layer[2].forEach(function (fd) {
          var r = body.insertRow();
          var off = fd[0] >= 0 ? ("0000" + fd[0].toString(16)).slice(-4) : "";
          var check = fd[4] || "";
          r.appendChild(el("td", off, "dim"));
          r.appendChild(el("td", fd[1], "dim"));
          r.appendChild(el("td", fd[2]));
          r.appendChild(el("td", fd[3]));
          r.appendChild(el("td", check ? "[" + check + "]" : "", check === "ok" ? "good" :
            (/BREAKS| error:| warning:/.test(check) ? "bad" : "dim")));
        });
      });
      div.appendChild(table);
      if (f.F.length) {
        var ul = el("ul", null, "findings");
        f.F.forEach(function (x) { ul.appendChild(el("li", x[0] + " " + x[1], "s-" + x[0])); });
        div.appendChild(ul);
      }
      box.appendChild(div);
    });
  }

  function openDrill(details) {
    if (!details || details.getAttribute("data-drawn")) { return; }
    details.setAttribute("data-drawn", "1");
    drawFrames(details.querySelector(".drill"), DATA.drill[details.getAttribute("data-txn")]);
  }

  document.querySelectorAll("div.pdtable").forEach(function (host) {
    makeTable(host, DATA.tables[host.getAttribute("data-table")]);
  });
  document.querySelectorAll("details[data-txn]").forEach(function (d) {
    d.addEventListener("toggle", function () { if (d.open) { openDrill(d); } });
  });
  function follow() {
    var m = /^#txn-(\d+)$/.exec(location.hash);
    var d = m && document.getElementById("txn-" + m[1]);
    if (d) { d.open = true; openDrill(d); d.scrollIntoView(); }
  }
  window.addEventListener("hashchange", follow);
  follow();
  document.body.setAttribute("data-ready", "1");
})();
