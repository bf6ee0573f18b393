// A vertex of a procedural model in its model frame, moved into the world by its joint
// (`gl_posed`): texels 4k .. 4k + 3 of the joint's row hold the rows of its [R | t] and the
// emission of the model's headlights (x) and tail lights (y).
// Uniforms: joints (JOINTS_PER_ROW joints to a texture row). Inputs: in_joint (its row).
uniform sampler2D joints;
in float in_joint;
const int JOINTS_PER_ROW = 256;
struct PosedVertex {
    vec3 position;
    vec3 normal;
    float emission;
};
PosedVertex posed_vertex(vec3 model_position, vec3 model_normal, float light_kind) {
    int joint = int(in_joint + 0.5);
    ivec2 texel = ivec2(4 * (joint % JOINTS_PER_ROW), joint / JOINTS_PER_ROW);
    vec4 row_x = texelFetch(joints, texel, 0);
    vec4 row_y = texelFetch(joints, texel + ivec2(1, 0), 0);
    vec4 row_z = texelFetch(joints, texel + ivec2(2, 0), 0);
    vec4 lights = texelFetch(joints, texel + ivec2(3, 0), 0);
    vec4 point = vec4(model_position, 1.0);
    PosedVertex posed;
    posed.position = vec3(dot(row_x, point), dot(row_y, point), dot(row_z, point));
    posed.normal = vec3(dot(row_x.xyz, model_normal), dot(row_y.xyz, model_normal),
                        dot(row_z.xyz, model_normal));
    // light kinds: 0 none, 1 headlight, 2 tail light (`ModelMesh.lights`)
    posed.emission = light_kind < 0.5 ? 0.0 : (light_kind < 1.5 ? lights.x : lights.y);
    return posed;
}
