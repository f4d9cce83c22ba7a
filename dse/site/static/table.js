// A table page: the rows embedded in the page (#table-data) in a Tabulator table (sortable, filterable
// per column, paginated), downloadable as CSV. An address ending in #column=value filters that column
// to that value: the link a claim gives to the rows behind it.
(function () {
  "use strict";
  var data = JSON.parse(document.getElementById("table-data").textContent);
  var element = document.getElementById("table");

  var columns = data.columns.map(function (c, i) {
    return {
      title: c.name + (c.unit ? " [" + c.unit + "]" : ""),
      field: "c" + i,
      sorter: c.type === "number" ? "number" : "string",
      headerFilter: "input",
      headerFilterFunc: c.type === "number" ? "=" : "like",
      headerTooltip: c.definition || c.name,
      hozAlign: c.type === "number" ? "right" : "left",
      maxWidth: 480,
    };
  });
  var rows = data.rows.map(function (r) {
    var o = {};
    r.forEach(function (v, i) { o["c" + i] = v; });
    return o;
  });
  var table = new Tabulator(element, {
    data: rows,
    columns: columns,
    layout: "fitDataStretch",
    pagination: true,
    paginationSize: 50,
    paginationSizeSelector: [25, 50, 200, 1000],
    movableColumns: true,
  });

  function fromHash() {
    var hash = decodeURIComponent(location.hash.slice(1));
    var eq = hash.indexOf("=");
    if (eq < 0) { return; }
    var name = hash.slice(0, eq), value = hash.slice(eq + 1);
    var index = data.columns.findIndex(function (c) { return c.name === name; });
    if (index >= 0) {
      var column = data.columns[index];
      table.clearHeaderFilter();
      table.setFilter("c" + index, "=", column.type === "number" ? Number(value) : value);
      shown.textContent = "Rows where " + name + " = " + value + ". ";
    }
  }
  var shown = document.createElement("span");
  shown.id = "hash-filter";
  element.parentNode.insertBefore(shown, element);
  table.on("tableBuilt", fromHash);
  window.addEventListener("hashchange", fromHash);
  document.getElementById("download-csv").addEventListener("click", function () {
    table.download("csv", element.dataset.name + ".csv", {}, "active");
  });
  document.getElementById("clear-filters").addEventListener("click", function () {
    table.clearHeaderFilter();
    table.clearFilter();
    shown.textContent = "";
  });
  window.dseTable = table;
})();
