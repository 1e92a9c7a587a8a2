/* pd-analyze HTML report, part 2: a transaction's frames and fields (the drill-down), opened from any txn link
   on the page (tables, summary text, timeline markers), every time it is clicked, and from #txn-N in the
   address. The field that decided a failed transaction's verdict is red and the frames open scrolled to it. */
(function (PD) {
  "use strict";
  var DATA = PD.DATA, el = PD.el;
  var CHECK = {E: "bad", F: "bad", R: "bad", W: "warn", N: "warn", I: "info", ok: "good"};
  var SEV = {error: "E", warning: "W", info: "I"};
  var txnRows = null;  /* txn number -> its row of the transactions table (built on first use) */

  function hex4(n) { return n >= 0 ? ("0000" + n.toString(16)).slice(-4) : ""; }

  function fieldRow(fd, depth, focus) {
    var tr = el("tr", null, "fld r-" + (fd[5] || "none"));
    tr.setAttribute("data-f", fd[2]);
    tr.appendChild(el("td", hex4(fd[0]), "off"));
    tr.appendChild(el("td", fd[1], "raw"));
    var name = el("td", fd[2], "name");
    name.style.paddingLeft = (4 + depth * 12) + "px";
    tr.appendChild(name);
    var show = el("td", fd[3], "show");
    if (fd[3].length >= DATA.cut) { show.title = "the value's first characters: pd-analyze dump shows it whole"; }
    tr.appendChild(show);
    var check = fd[4] || (fd[5] === "R" ? "refused by the drive" : "");
    tr.appendChild(el("td", check ? "[" + check + "]" : "", "check " + (CHECK[fd[5]] || "dim")));
    if (focus) { tr.className += focus; }
    return tr;
  }

  function layerBody(layer, focusName, focusCls) {
    var body = el("tbody", null, "layer" + (layer[3] ? " folded" : ""));
    var head = body.insertRow(), td = el("td");
    head.className = "lhead";
    td.colSpan = 5;
    td.style.paddingLeft = (layer[1] * 12) + "px";
    var button = el("button", layer[0], "fold");
    button.type = "button";
    button.setAttribute("aria-expanded", layer[3] ? "false" : "true");
    button.appendChild(el("span", " " + layer[2].length + " field" + (layer[2].length === 1 ? "" : "s"), "dim"));
    button.addEventListener("click", function () {
      var folded = body.classList.toggle("folded");
      button.setAttribute("aria-expanded", folded ? "false" : "true");
    });
    td.appendChild(button);
    head.appendChild(td);
    layer[2].forEach(function (fd) {
      body.appendChild(fieldRow(fd, layer[1], fd[2] === focusName ? focusCls : ""));
    });
    return body;
  }

  function spanRow(cls, text) {
    var body = el("tbody", null, cls), td = el("td", text);
    td.colSpan = 5;
    body.insertRow().appendChild(td);
    return body;
  }

  function findingsBody(frame, table) {
    var body = el("tbody", null, "ffind"), td = el("td"), ul = el("ul", null, "findings");
    td.colSpan = 5;
    frame.F.forEach(function (x) {  /* [severity, rule, name, field, message, value, expected] */
      var detail = [];
      if (x[5]) { detail.push("value " + x[5]); }
      if (x[6]) { detail.push("expected " + x[6]); }
      var li = el("li", (SEV[x[0]] || "?") + " " + x[1] + " " + x[2] + " [" + x[3] + "]: " + x[4] +
        (detail.length ? " (" + detail.join("; ") + ")" : ""), "s-" + x[0]);
      li.setAttribute("data-field", x[3]);
      li.title = "show the field";
      li.addEventListener("click", function () {
        var row = findRow(table, frame.n, x[3]);
        if (row) { unfold(row); reveal(row, true); }
      });
      ul.appendChild(li);
    });
    if (frame.more) { ul.appendChild(el("li", "\u2026 " + frame.more + " more findings at this frame: the Findings table " +
      "lists them", "dim")); }
    td.appendChild(ul);
    body.insertRow().appendChild(td);
    return body;
  }

  function findRow(table, n, name) {
    var rows = table.querySelectorAll("tr.fld[data-frame='" + n + "']");
    for (var k = 0; k < rows.length; k++) { if (rows[k].getAttribute("data-f") === name) { return rows[k]; } }
    return null;
  }
  function unfold(row) { row.parentNode.classList.remove("folded"); }

  function drawFrames(box, drill) {
    if (!drill || !drill.F.length) {
      box.appendChild(el("p", "No frame of this transaction was found again in the capture.", "dim"));
      return;
    }
    var focus = drill.x, failed = drill.v !== "ok";
    var focusCls = failed ? " decisive" : " focus";
    var scroller = el("div", null, "fbox"), table = el("table", null, "fields");
    var colgroup = el("colgroup");
    ["c-off", "c-raw", "c-name", "c-show", "c-check"].forEach(function (c) { colgroup.appendChild(el("col", null, c)); });
    table.appendChild(colgroup);
    var hrow = table.createTHead().insertRow();
    ["offset", "bytes", "field", "value", "check"].forEach(function (h) { hrow.appendChild(el("th", h)); });
    drill.F.forEach(function (f) {
      if (f.gap) {
        table.appendChild(spanRow("gap", "\u2026 " + f.gap + " frame" + (f.gap === 1 ? "" : "s") + " left out \u2026"));
        return;
      }
      var decided = focus && focus[0] === f.n;
      var head = spanRow("fhead", "Frame " + f.n + " \u00b7 " + f.t + " \u00b7 " + f.src + " \u2192 " + f.dst +
        " \u00b7 " + f.s);
      head.setAttribute("data-frame", String(f.n));
      if (decided && failed) {
        head.rows[0].cells[0].appendChild(el("span", "  the field in red decided the verdict (" + drill.v + ")",
          "decided"));
      }
      table.appendChild(head);
      f.L.forEach(function (layer) {
        var body = layerBody(layer, decided ? focus[1] : null, focusCls);
        body.querySelectorAll("tr.fld").forEach(function (r) { r.setAttribute("data-frame", String(f.n)); });
        table.appendChild(body);
      });
      if (f.F.length) { table.appendChild(findingsBody(f, table)); }
    });
    scroller.appendChild(table);
    box.appendChild(scroller);
  }

  /* Scroll the frames' box to a row (the page too when asked), and let it blink. */
  function reveal(row, page) {
    var box = row.closest(".fbox");
    if (page) { box.scrollIntoView({block: "nearest"}); }
    box.scrollTop = Math.max(0, row.offsetTop - box.clientHeight / 3);
    row.classList.remove("flash");
    void row.offsetWidth;  /* restart the animation */
    row.classList.add("flash");
  }

  function draw(details) {
    if (!details.getAttribute("data-drawn")) {
      details.setAttribute("data-drawn", "1");
      var txn = details.getAttribute("data-txn"), drill = DATA.drill[txn];
      var box = details.querySelector(".drill");
      if (drill) { drawFrames(box, drill); } else { notEmbedded(box, txn); }
    }
    var target = details.querySelector("tr.decisive, tr.focus");
    if (target) { reveal(target, false); }
  }

  function transactionRow(txn) {
    var spec = DATA.tables.transactions;
    if (!txnRows) {
      txnRows = {};
      var at = spec.columns.findIndex(function (c) { return c.name === "txn"; });
      spec.rows.forEach(function (r) { txnRows[r[at]] = r; });
    }
    var row = txnRows[txn];
    if (!row) { return null; }
    var out = {};
    spec.columns.forEach(function (c, i) { out[c.name] = row[i]; });
    return out;
  }

  function notEmbedded(box, txn) {
    var r = transactionRow(txn), capture = (r && r.capture) || DATA.capture || "CAPTURE";
    box.appendChild(el("p", "The frames of this transaction are not embedded in this page (it holds those of the " +
      "failed transactions, of those the summary names and of a few more). This command shows them:", "dim"));
    box.appendChild(el("pre", "pd-analyze dump '" + capture.replace(/'/g, "'\\''") + "' -Y 'txn.id == " + txn + "'"));
  }

  /* A drill-down for a transaction without one on the page: its heading from the transactions table. */
  function makeDetails(txn) {
    var r = transactionRow(txn), details = el("details"), summary = el("summary");
    details.id = "txn-" + txn;
    details.setAttribute("data-txn", txn);
    summary.appendChild(el("span", "txn " + txn, "txn"));
    if (r) {
      summary.appendChild(document.createTextNode(" "));
      summary.appendChild(el("span", r.verdict, "badge v-" + r.verdict));
      var what = [[r.device, r.do !== null ? "DO " + r.do : null, r.ref !== null ? "ref " + r.ref : null]
        .filter(function (w) { return w; }).join(" "), r.params, r.errors || r.pnio_error_text];
      var n = r.frames ? String(r.frames).split(" ").length : 0;
      what.push(n + " frame" + (n === 1 ? "" : "s"));
      what.forEach(function (w) {
        if (w) { summary.appendChild(el("span", " \u00b7 ", "sep")); summary.appendChild(document.createTextNode(w)); }
      });
    } else {
      summary.appendChild(el("span", " (not among the embedded rows: see the CSV files)", "dim"));
    }
    details.appendChild(summary);
    details.appendChild(el("div", null, "drill"));
    details.addEventListener("toggle", function () { if (details.open) { draw(details); } });
    document.getElementById("more-txns").appendChild(details);
    return details;
  }

  function openTxn(txn) {
    var details = document.getElementById("txn-" + txn) || makeDetails(txn);
    details.open = true;
    draw(details);
    details.scrollIntoView({block: "start"});
    var target = details.querySelector("tr.decisive, tr.focus");
    if (target) { reveal(target, false); }
  }

  document.querySelectorAll("details[data-txn]").forEach(function (d) {
    d.addEventListener("toggle", function () { if (d.open) { draw(d); } });
  });
  document.addEventListener("click", function (e) {
    var a = e.target.closest && e.target.closest("a[href^='#txn-']");
    if (!a || e.button !== 0 || e.ctrlKey || e.metaKey || e.shiftKey) { return; }  /* a new tab: it follows #txn-N */
    e.preventDefault();
    var href = a.getAttribute("href");
    if (location.hash !== href) {  /* the address names the transaction (back goes back), without a jump */
      try { history.pushState(null, "", href); } catch (err) { location.hash = href; }
    }
    openTxn(href.slice(5));
  });
  function follow() {
    var m = /^#txn-(\d+)$/.exec(location.hash);
    if (m) { openTxn(m[1]); }
  }
  window.addEventListener("hashchange", follow);
  window.addEventListener("popstate", follow);
  follow();
  document.body.setAttribute("data-ready", "1");
})(PD);
