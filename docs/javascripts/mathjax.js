// MathJax for the equations: $...$ and \(...\) inline, $$...$$ and \[...\] displayed, in the
// pages (pymdownx.arithmatex), the docstrings (mkdocstrings) and the notebooks.
window.MathJax = {
  tex: {
    inlineMath: [["\\(", "\\)"], ["$", "$"]],
    displayMath: [["\\[", "\\]"], ["$$", "$$"]],
    processEscapes: true,
    processEnvironments: true,
  },
  options: {ignoreHtmlClass: "tex2jax_ignore", processHtmlClass: "tex2jax_process|arithmatex"},
};

document$.subscribe(() => {
  MathJax.typesetPromise();
});
