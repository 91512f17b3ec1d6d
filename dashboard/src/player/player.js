// The replay player on the session review (docs/dashboard.md "Player"). The page works without
// this script (key moments are links to their frames); with it: play, pause, speed, the timeline,
// key moments, keyboard shortcuts and a cursor on the time charts that a click moves.
// Frames come from GET /sessions/{id}/frame, drawn on the server from the replay; while playing,
// the next tick is asked for only when the frames of the last one have arrived (or were given up
// after LOAD_TIMEOUT_MS), so a slow server lowers the frame rate, not what is shown. Playing
// steps on a grid of a tenth of a second, so that viewers share the server's cached frames.
(function () {
  "use strict";
  var player = document.getElementById("player");
  if (!player) return;
  var id = player.dataset.session;
  var rate = Number(player.dataset.rate);
  var last = Number(player.dataset.last);
  var w = player.dataset.w, h = player.dataset.h;
  var timeline = document.getElementById("timeline");
  var clock = document.getElementById("clock");
  var playButton = document.getElementById("play");
  var speedSelect = document.getElementById("speed");
  var speeds = [0.25, 0.5, 1, 2, 4, 8];
  var images = Array.prototype.slice.call(player.querySelectorAll("img[data-view]"));
  var tick = Number(player.dataset.tick);
  var playing = false;
  var loading = 0;
  var wanted = null;
  var generation = 0;
  var LOAD_TIMEOUT_MS = 15000;
  var grid = Math.max(1, Math.round(rate / 10));

  function src(view, t) {
    return "/sessions/" + encodeURIComponent(id) + "/frame?view=" + view + "&tick=" + t + "&w=" + w + "&h=" + h;
  }

  // The time charts (force, depth): a cursor line each, moved with the tick; a click seeks.
  var charts = Array.prototype.slice.call(document.querySelectorAll("svg.chart[data-x0]"));
  var SVG = "http://www.w3.org/2000/svg";
  charts.forEach(function (svg, n) {
    var line = document.createElementNS(SVG, "line");
    line.setAttribute("class", "player-cursor");
    line.setAttribute("id", "cursor-" + n);
    line.setAttribute("stroke", "#d0021b");
    line.setAttribute("stroke-width", "2");
    var box = svg.viewBox && svg.viewBox.baseVal;
    line.setAttribute("y1", "0");
    line.setAttribute("y2", box && box.height ? String(box.height) : "440");
    svg.appendChild(line);
    svg.style.cursor = "crosshair";
    svg.addEventListener("click", function (e) {
      var ctm = svg.getScreenCTM();
      if (!ctm) return;
      var pt = svg.createSVGPoint();
      pt.x = e.clientX;
      pt.y = e.clientY;
      var x = pt.matrixTransform(ctm.inverse()).x;
      var d = svg.dataset;
      var t = Number(d.x0) + (x - Number(d.px0)) / (Number(d.px1) - Number(d.px0)) * (Number(d.x1) - Number(d.x0));
      seek(Math.round(t * rate));
    });
  });

  function moveCursors(at) {
    var t = at / rate;
    charts.forEach(function (svg, n) {
      var d = svg.dataset;
      var x = Number(d.px0) + (t - Number(d.x0)) / (Number(d.x1) - Number(d.x0)) * (Number(d.px1) - Number(d.px0));
      var line = document.getElementById("cursor-" + n);
      line.setAttribute("x1", String(x));
      line.setAttribute("x2", String(x));
      line.setAttribute("data-t", t.toFixed(3));
    });
  }

  // The clock and the chart cursors at tick t.
  function setClock(t) {
    clock.textContent = (t / rate).toFixed(2) + " s";
    timeline.setAttribute("aria-valuetext", clock.textContent);
    moveCursors(t);
  }

  // Shows tick t: the timeline at once; the frames when they arrive. A seek moves the clock at
  // once (the viewer chose the time); while playing the clock follows the frames on screen, so it
  // never runs ahead of the pictures nor jumps while the server draws.
  function show(t) {
    tick = Math.max(0, Math.min(last, t));
    player.dataset.tick = String(tick);
    timeline.value = String(tick);
    if (!playing) setClock(tick);
    if (loading > 0) {
      wanted = tick;
      return;
    }
    load(tick);
  }

  // Loads the four frames of tick t; when all have arrived (or failed, or LOAD_TIMEOUT_MS passed),
  // the tick counts as shown and the latest tick asked for meanwhile is loaded next.
  function load(t) {
    generation += 1;
    var mine = generation;
    var left = images.length;
    var failed = false;
    loading = left;
    var arrived = [];
    var finish = function () {
      if (mine !== generation) return;
      loading = 0;
      if (!failed) {
        // All four views change together, with the clock while playing.
        arrived.forEach(function (a) {
          a.img.src = a.src;
          a.img.dataset.tick = String(t);
          a.img.alt = a.img.alt.replace(/ at .*$/, " at " + (t / rate).toFixed(2) + " s");
        });
        player.dataset.shown = String(t);
        if (playing || t === tick) setClock(t);
        // Playing time starts when the first frames of a play are on screen, not when they
        // were asked for: a slow first drawing does not make the clock jump.
        if (playing && !started) {
          started = true;
          lastStep = null;
        }
      }
      if (wanted !== null && wanted !== t) {
        var next = wanted;
        wanted = null;
        load(next);
      } else {
        wanted = null;
      }
    };
    var timer = window.setTimeout(function () { failed = true; finish(); }, LOAD_TIMEOUT_MS);
    images.forEach(function (img) {
      var next = new Image();
      var done = function (ok) {
        if (mine !== generation) return;
        if (ok && next.naturalWidth > 0) {
          arrived.push({ img: img, src: next.src });
        } else {
          failed = true;
        }
        left -= 1;
        loading = left;
        if (left === 0) {
          window.clearTimeout(timer);
          finish();
        }
      };
      next.onload = function () { done(true); };
      next.onerror = function () { done(false); };
      next.src = src(img.dataset.view, t);
    });
  }

  function seek(t) {
    show(t);
  }

  var lastStep = null;
  // Whether the first frames of the current play have been shown.
  var started = false;
  function step(now) {
    if (!playing) return;
    if (lastStep !== null && loading === 0) {
      var speed = Number(speedSelect.value);
      var advance = Math.max(grid, Math.round((now - lastStep) * speed * rate / 1000 / grid) * grid);
      if (tick >= last) {
        setPlaying(false);
        return;
      }
      show(Math.min(last, Math.floor((tick + advance) / grid) * grid));
      lastStep = now;
    } else if (lastStep === null) {
      lastStep = now;
    }
    frameRequest = window.requestAnimationFrame(step);
  }

  var frameRequest = null;
  function setPlaying(on) {
    playing = on;
    playButton.textContent = on ? "Pause" : "Play";
    playButton.setAttribute("aria-pressed", on ? "true" : "false");
    player.dataset.playing = on ? "1" : "0";
    if (frameRequest !== null) {
      window.cancelAnimationFrame(frameRequest);
      frameRequest = null;
    }
    if (on) {
      if (tick >= last) show(0);
      lastStep = null;
      started = false;
      frameRequest = window.requestAnimationFrame(step);
    }
  }

  function changeSpeed(by) {
    var i = speeds.indexOf(Number(speedSelect.value));
    i = Math.max(0, Math.min(speeds.length - 1, i + by));
    speedSelect.value = String(speeds[i]);
  }

  playButton.addEventListener("click", function () { setPlaying(!playing); });
  timeline.addEventListener("input", function () { seek(Number(timeline.value)); });
  Array.prototype.forEach.call(player.querySelectorAll("a.moment"), function (a) {
    a.addEventListener("click", function (e) {
      e.preventDefault();
      setPlaying(false);
      seek(Number(a.dataset.tick));
    });
  });
  // Keys act when the focus is in the player or on nothing in particular (the page's body), so
  // the review's forms, buttons and links keep theirs.
  document.addEventListener("keydown", function (e) {
    var target = e.target || document.body;
    var inPlayer = player.contains(target);
    if (!inPlayer && target !== document.body && target !== document.documentElement) return;
    if (target.isContentEditable || e.ctrlKey || e.metaKey || e.altKey) return;
    var tag = target.tagName || "";
    if (tag === "SELECT" || (tag === "INPUT" && target !== timeline)) return;
    var handled = true;
    switch (e.key) {
      case " ":
        if (tag === "BUTTON" || tag === "A") return;
        setPlaying(!playing);
        break;
      case "ArrowLeft": seek(tick - rate); break;
      case "ArrowRight": seek(tick + rate); break;
      case "[": changeSpeed(-1); break;
      case "]": changeSpeed(1); break;
      case "Home": seek(0); break;
      case "End": seek(last); break;
      default: handled = false;
    }
    if (handled) e.preventDefault();
  });
  // The page's own frames count as shown once they have loaded.
  (function () {
    var left = images.length;
    loading = left;
    images.forEach(function (img) {
      var done = function () {
        left -= 1;
        if (left > 0) return;
        loading = 0;
        player.dataset.shown = String(tick);
        if (wanted !== null) {
          var next = wanted;
          wanted = null;
          load(next);
        }
      };
      if (img.complete) done();
      else {
        img.addEventListener("load", done, { once: true });
        img.addEventListener("error", done, { once: true });
      }
    });
  })();
  // With the script: the controls, not the note for browsers without it.
  Array.prototype.forEach.call(player.querySelectorAll("[hidden]"), function (el) { el.hidden = false; });
  Array.prototype.forEach.call(player.querySelectorAll(".noscript-only"), function (el) { el.remove(); });
  player.dataset.ready = "1";
  moveCursors(tick);
})();

// The 3D overview's turntable (docs/dashboard.md "3D overview"): the arrows, dragging the
// picture sideways (mouse, pen or touch) and ← → on it turn it one frame (30°); the frame shown
// is in data-frame, and data-shown once it has loaded.
(function () {
  "use strict";
  var box = document.getElementById("overview");
  if (!box) return;
  var img = document.getElementById("overview-frame");
  var frames = Number(box.dataset.frames);
  var frame = Number(box.dataset.frame);
  var url = function (f) {
    return "/sessions/" + box.dataset.session + "/overview?frame=" + f + "&e=" + box.dataset.key;
  };
  var turn = function (by) {
    frame = (((frame + by) % frames) + frames) % frames;
    box.dataset.frame = String(frame);
    img.src = url(frame);
    img.alt = img.alt.replace(/azimuth \d+°/, "azimuth " + frame * (360 / frames) + "°");
  };
  img.addEventListener("load", function () { box.dataset.shown = String(frame); });
  if (img.complete) box.dataset.shown = String(frame);
  var arrow = function (id, by) {
    var a = document.getElementById(id);
    a.addEventListener("click", function (e) { e.preventDefault(); turn(by); });
  };
  arrow("turn-left", -1);
  arrow("turn-right", 1);
  img.tabIndex = 0;
  img.addEventListener("keydown", function (e) {
    if (e.key === "ArrowLeft") { turn(-1); e.preventDefault(); }
    if (e.key === "ArrowRight") { turn(1); e.preventDefault(); }
  });
  var dragX = null;
  img.addEventListener("pointerdown", function (e) {
    dragX = e.clientX;
    try { img.setPointerCapture(e.pointerId); } catch (err) { /* a pointer the page cannot capture */ }
    e.preventDefault();
  });
  img.addEventListener("pointermove", function (e) {
    if (dragX === null) return;
    var steps = Math.trunc((e.clientX - dragX) / 40);
    if (steps !== 0) { dragX += steps * 40; turn(-steps); }
  });
  var end = function () { dragX = null; };
  img.addEventListener("pointerup", end);
  img.addEventListener("pointercancel", end);
  box.dataset.ready = "1";
})();
