// A full-screen triangle; fragments address pixels by gl_FragCoord (row 0 = image top in
// the page's own targets).
void main() {
  vec2 p = vec2(gl_VertexID == 1 ? 3.0 : -1.0, gl_VertexID == 2 ? 3.0 : -1.0);
  gl_Position = vec4(p, 0.0, 1.0);
}
