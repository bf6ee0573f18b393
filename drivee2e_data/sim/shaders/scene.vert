#version 330
// The scene pass's vertex stage: world-space vertices to clip space.
// Uniforms: mvp (view-projection), shadow_matrix (world to the sun's shadow-map space).
uniform mat4 mvp;
uniform mat4 shadow_matrix;
in vec3 in_position;
in vec3 in_normal;
in vec3 in_colour;
in float in_body;
in float in_emission;
in float in_material;
out vec3 world_position;
out vec3 normal;
out vec3 colour;
out float eye_depth;
out vec4 shadow_position;
flat out float body;
flat out float emission;
flat out int material;
void main() {
    gl_Position = mvp * vec4(in_position, 1.0);
    eye_depth = gl_Position.w;  // a perspective projection's w: the depth along the view axis
    world_position = in_position;
    // a little towards the normal, so that a surface does not shadow itself (normal offset)
    shadow_position = shadow_matrix * vec4(in_position + 0.04 * in_normal, 1.0);
    normal = in_normal;
    colour = in_colour;
    body = in_body;
    emission = in_emission;
    material = int(in_material + 0.5);
}
