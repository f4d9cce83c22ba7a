// Opens a recording of the page in the Rerun web viewer (static/viewer/widget.js, from the rerun-notebook
// package of the pinned rerun version). The viewer module is written for Jupyter widgets: it is given here
// the few members of a widget model it reads (the recording's address, its size), and nothing else.
import viewer from "./viewer/widget.js";

const container = document.getElementById("viewer");

// The site works offline and asks nothing of any other host: the viewer's check for a newer rerun release
// (a request to api.github.com at start-up) is answered here with "not found", which it treats as no news.
const siteFetch = window.fetch.bind(window);
window.fetch = (resource, init) => {
  const url = new URL(resource instanceof Request ? resource.url : String(resource), document.baseURI);
  if (url.protocol.startsWith("http") && url.origin !== location.origin) {
    return Promise.resolve(new Response(null, { status: 404, statusText: "not requested: an offline site" }));
  }
  return siteFetch(resource, init);
};
let stop = null;
window.dseViewerEvents = [];

function model(url) {
  const values = { _url: url, _width: "auto", _height: 640, _panel_states: null, _fallback_token: null, _theme: null };
  // The viewer's events (ready, and its raw events as JSON) are kept for whoever inspects the page.
  const send = (event) => { window.dseViewerEvents.push(typeof event === "string" ? event : JSON.stringify(event)); };
  return { get: (key) => values[key], on: () => {}, send };
}

function open(rrd) {
  if (stop) { stop(); stop = null; }
  container.replaceChildren();
  container.hidden = false;
  container.dataset.rrd = rrd;
  const url = new URL(rrd, document.baseURI).href;
  stop = viewer.render({ model: model(url), el: container });
  container.scrollIntoView({ block: "start" });
}

document.querySelectorAll(".open-recording").forEach((button) => {
  button.addEventListener("click", (event) => {
    event.preventDefault();
    open(button.dataset.rrd);
  });
});
const wanted = new URLSearchParams(location.search).get("recording");
if (wanted) { open(wanted); }
window.dseOpenRecording = open;
