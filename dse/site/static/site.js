// The claim filter (by verdict, by paper or run, by text) of the index, run and sweep pages.
// Its state is kept in the address (?verdict=fail&paper=savas&text=riccati) so a filtered view can be linked.
(function () {
  "use strict";

  function apply(form) {
    var verdict = form.elements.verdict ? form.elements.verdict.value : "";
    var paper = form.elements.paper ? form.elements.paper.value : "";
    var text = form.elements.text ? form.elements.text.value.trim().toLowerCase() : "";
    var rows = document.querySelectorAll("[data-claim]");
    var shown = 0;
    rows.forEach(function (row) {
      var ok = (!verdict || row.dataset.verdict.split(" ").indexOf(verdict) >= 0) &&
        (!paper || row.dataset.paper === paper) &&
        (!text || row.dataset.text.indexOf(text) >= 0);
      row.hidden = !ok;
      if (ok) { shown += 1; }
    });
    var out = form.querySelector(".shown");
    if (out) { out.textContent = shown + " of " + rows.length + " claims"; }
    var params = new URLSearchParams(location.search);
    [["verdict", verdict], ["paper", paper], ["text", text]].forEach(function (kv) {
      if (kv[1]) { params.set(kv[0], kv[1]); } else { params.delete(kv[0]); }
    });
    var query = params.toString();
    history.replaceState(null, "", location.pathname + (query ? "?" + query : "") + location.hash);
  }

  function setUp(form) {
    var params = new URLSearchParams(location.search);
    ["verdict", "paper", "text"].forEach(function (name) {
      if (form.elements[name] && params.get(name)) { form.elements[name].value = params.get(name); }
    });
    form.addEventListener("input", function () { apply(form); });
    form.addEventListener("change", function () { apply(form); });
    if (params.get("verdict") || params.get("paper") || params.get("text")) { apply(form); }
  }

  document.querySelectorAll("form.claim-filter").forEach(setUp);
})();

// The web viewer (static/viewer.js, an ES module) is loaded on pages served over HTTP; a page opened from a
// file says how to serve the site instead (browsers load neither modules nor WebAssembly from file://).
(function () {
  "use strict";
  var viewer = document.getElementById("viewer");
  if (!viewer) { return; }
  if (location.protocol === "file:") {
    document.querySelectorAll("button.open-recording").forEach(function (b) { b.disabled = true; });
    document.querySelectorAll(".note.file-only").forEach(function (n) { n.hidden = false; });
    return;
  }
  var script = document.createElement("script");
  script.type = "module";
  script.src = viewer.dataset.module;
  document.body.appendChild(script);
})();

// A link to a claim (#claim-<id>) opens its detail and evidence, and shows it even when the filter hid it.
(function () {
  "use strict";
  function openTarget() {
    var id = decodeURIComponent(location.hash.slice(1));
    var row = id && document.getElementById(id);
    if (!row || !row.hasAttribute("data-claim")) { return; }
    row.hidden = false;
    var details = row.querySelector("details");
    if (details) { details.open = true; }
  }
  window.addEventListener("hashchange", openTarget);
  openTarget();
})();
