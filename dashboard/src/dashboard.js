// The pages' one script (docs/dashboard.md). The Content-Security-Policy (script-src 'self')
// blocks inline handlers, so no page has one: an element names what it does in `data-action`
// and this file, served at /assets/dashboard.js, binds it. Pages work without it: elements that
// need it are rendered `hidden` and shown here.
(function () {
  "use strict";
  var actions = {
    // Looked up at click time, so a test can stand in for window.print.
    print: function () { window.print(); }
  };
  function show() {
    document.querySelectorAll("[data-action][hidden]").forEach(function (el) {
      if (actions[el.dataset.action]) el.hidden = false;
    });
  }
  if (document.readyState === "loading") {
    document.addEventListener("DOMContentLoaded", show);
  } else {
    show();
  }
  document.addEventListener("click", function (e) {
    var el = e.target && e.target.closest ? e.target.closest("[data-action]") : null;
    if (!el || !actions[el.dataset.action]) return;
    e.preventDefault();
    actions[el.dataset.action](el, e);
  });
})();
