const pics = JSON.parse(document.getElementById("pics").textContent);
for (const img of document.querySelectorAll("img[data-pic]")) img.src = pics[img.dataset.pic];
const state = {method: "all", outcome: "all"};
function apply() {
  let n = 0;
  for (const s of document.querySelectorAll(".strip")) {
    const show = (state.method === "all" || s.dataset.method === state.method)
      && (state.outcome === "all" || s.dataset.outcome === state.outcome);
    s.style.display = show ? "" : "none";
    if (show) n++;
  }
  document.getElementById("shown").textContent = n + " shown";
  for (const b of document.querySelectorAll("button[data-filter]"))
    b.classList.toggle("on", state[b.dataset.filter] === b.dataset.value);
}
for (const b of document.querySelectorAll("button[data-filter]"))
  b.addEventListener("click", () => { state[b.dataset.filter] = b.dataset.value; apply(); });
for (const a of document.querySelectorAll("a[data-method]"))
  a.addEventListener("click", () => { state.method = a.dataset.method; state.outcome = "all"; apply(); });
// a similarity matrix: the pair under the pointer said, a click shows that pair's frames (the nearest embedded)
const pairsEl = document.getElementById("pairs");
const pairs = pairsEl ? JSON.parse(pairsEl.textContent) : null;
for (const button of document.querySelectorAll("button.full-size"))
  button.addEventListener("click", () => {
    const fig = button.closest("figure");
    fig.classList.toggle("full");
    fig.querySelector("img.matrix").classList.toggle("full");
  });
function nearest(side, i) {
  let k = Math.min(side.index.length - 1, Math.max(0, Math.round(i / side.step)));
  return k;
}
for (const img of document.querySelectorAll("img.matrix")) {
  const [x0, y0, x1, y1] = JSON.parse(img.dataset.box), [rows, cols] = JSON.parse(img.dataset.shape);
  const names = JSON.parse(img.dataset.labels), fig = img.closest("figure"), at = fig.querySelector(".at");
  const box = fig.querySelector(".pair");
  const pair = e => {
    const r = img.getBoundingClientRect();
    const fx = ((e.clientX - r.left) / r.width - x0) / (x1 - x0);
    const fy = ((e.clientY - r.top) / r.height - y0) / (y1 - y0);
    if (fx < 0 || fx >= 1 || fy < 0 || fy >= 1) return null;
    return [Math.floor(fy * rows), Math.floor(fx * cols)];
  };
  img.addEventListener("mousemove", e => {
    const p = pair(e);
    at.textContent = p ? `${names[0]} ${p[0]}, ${names[1]} ${p[1]}` : "";
  });
  img.addEventListener("click", e => {
    const p = pair(e);
    if (!p || !pairs) return;
    box.textContent = "";
    const sides = [[pairs.columns || pairs.rows, p[1], names[1]], [pairs.rows, p[0], names[0]]];
    for (const [side, asked, label] of sides) {
      const k = nearest(side, asked), f = document.createElement("figure"), im = document.createElement("img");
      if (side.pics[k]) im.src = side.pics[k];
      im.title = side.names[k];
      im.alt = `${label} ${side.index[k]}`;
      const cap = document.createElement("figcaption");
      cap.textContent = `${label} ${side.index[k]}: ${side.captions[k]}`
        + (side.index[k] !== asked ? ` (the nearest embedded to ${asked})` : "");
      f.append(im, cap);
      box.append(f);
    }
    const strip = document.getElementById(`s-${img.dataset.method}-${p[1]}`);
    if (strip) {
      const a = document.createElement("a");
      a.href = "#" + strip.id;
      a.textContent = `${names[1]} ${p[1]}'s decision below`;
      a.addEventListener("click", () => { state.method = img.dataset.method; state.outcome = "all"; apply(); });
      box.append(a);
    }
    box.dataset.row = p[0];
    box.dataset.column = p[1];
    at.textContent = `${names[0]} ${p[0]}, ${names[1]} ${p[1]}`;
  });
}
apply();
