#version 330
// The sun's shadow map: depth only (the depth buffer is the output).
// Uniforms: none.
void main() {
}
