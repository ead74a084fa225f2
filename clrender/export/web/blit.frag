// The frame (image row 0 at framebuffer row 0) onto the canvas (row 0 at the bottom).
uniform sampler2D frame;
out vec4 colour;
void main() {
  ivec2 p = ivec2(gl_FragCoord.xy);
  colour = vec4(clamp(texelFetch(frame, ivec2(p.x, size.y - 1 - p.y), 0).rgb, 0.0, 1.0), 1.0);
}
